"""One answerer over transformers' ``AutoProcessor`` and chat templates, for every record of
:mod:`probes.vlm.specs` (and the random-weight fixtures of :mod:`probes.vlm.tiny`).

A batch of prompts becomes one chat per prompt (images first, then the protocol text), rendered by the
processor's chat template, left-padded and generated greedily (``do_sample=False``) with the record's
``max_new_tokens``; the reply is the decoded new tokens. bf16 (the record's dtype) on GPU, float32 on CPU;
``device_map="auto"`` for models of 20B parameters and more when a GPU is there (accelerate spreads them over
the visible GPUs and CPU memory).

Weights come from the Hugging Face cache and are downloaded into it when missing, unless ``HF_HUB_OFFLINE=1``
or ``allow_download=False``: then :class:`~probes.backbones.weights.WeightsUnavailableError` says how to
provide them. The manifest records the resolved commit of the snapshot.

Family adapters (:data:`FAMILY_ADAPTERS`) override only how a prompt is rendered: PaliGemma has no chat
template (a task prefix, the processor adds the image tokens).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from pathlib import Path
from typing import Any

import torch

from probes.backbones.weights import WeightsUnavailableError, hf_cache_dir, hf_offline
from probes.vlm.interface import Generation, Prompt
from probes.vlm.specs import VLMSpec, get_spec

log = logging.getLogger(__name__)

SNAPSHOT_PATTERNS: tuple[str, ...] = ("*.json", "*.safetensors", "*.jinja", "*.model", "*.txt", "*.tiktoken")
"""Files of a repo a load needs (no duplicate ``.bin`` / ``.pth`` weights, no remote code)."""
DTYPES: dict[str, torch.dtype] = {"bfloat16": torch.bfloat16, "float16": torch.float16, "float32": torch.float32}
LARGE_MODEL_PARAMS_B = 20.0
"""Models from this size (billions of parameters) load with ``device_map="auto"`` on GPU."""


def missing_vlm_message(spec: VLMSpec, what: str) -> str:
    return (
        f"weights of VLM {spec.name!r} ({what} of Hugging Face repo {spec.hf_id!r}) are not available locally: "
        f"not in the HF cache {str(hf_cache_dir())!r} (HF_HUB_OFFLINE={os.environ.get('HF_HUB_OFFLINE', '<unset>')}). "
        f"Provide them in one of these ways: (1) on a machine with network run `huggingface-cli download "
        f"{spec.hf_id}` and copy the cache to {str(hf_cache_dir())!r} (or point HF_HOME / HF_HUB_CACHE at a cache "
        f"that has it){'; the repo is gated: accept its terms and set HF_TOKEN' if spec.gated else ''}; "
        f"(2) pass a local copy: vlm.weights_path=/path/to/snapshot; (3) let it download here: unset "
        f"HF_HUB_OFFLINE (and keep vlm.allow_download true, the default)."
    )


def resolve_snapshot(spec: VLMSpec, revision: str | None, weights_path: str | os.PathLike[str] | None,
                     allow_download: bool) -> tuple[Path, str]:  # fmt: skip
    """(local directory of the model's files, resolved revision: the snapshot's commit or ``local``)."""
    if weights_path is not None:
        path = Path(weights_path).expanduser()
        if not (path / "config.json").is_file():
            raise WeightsUnavailableError(
                f"weights_path={str(path)!r} for VLM {spec.name!r} must be a directory holding config.json, the "
                "weights and the processor files (a snapshot of the repo)"
            )
        return path, "local"
    from huggingface_hub import snapshot_download
    from huggingface_hub.errors import LocalEntryNotFoundError

    cache = hf_cache_dir()
    try:
        snap = Path(snapshot_download(spec.hf_id, revision=revision, cache_dir=cache, local_files_only=True,
                                      allow_patterns=list(SNAPSHOT_PATTERNS)))  # fmt: skip
        if (snap / "config.json").is_file():
            return snap, snap.name
    except LocalEntryNotFoundError:
        log.debug("%s (revision %s) is not in the cache %s", spec.hf_id, revision or "main", cache)
    if allow_download and not hf_offline():
        log.info("downloading %s (revision %s) into %s", spec.hf_id, revision or "main", cache)
        try:
            snap = Path(snapshot_download(spec.hf_id, revision=revision, cache_dir=cache,
                                          allow_patterns=list(SNAPSHOT_PATTERNS)))  # fmt: skip
        except Exception as e:  # network, auth, missing repo: say what failed and how to provide the weights
            raise WeightsUnavailableError(
                f"downloading {spec.hf_id!r} failed: {type(e).__name__}: {e}. "
                + missing_vlm_message(spec, "a snapshot")
            ) from e
        return snap, snap.name
    raise WeightsUnavailableError(missing_vlm_message(spec, "a snapshot with config.json"))


def pick_device(device: str | None) -> str:
    """``auto`` / None -> ``cuda`` when a GPU is visible, else ``cpu``."""
    if device in (None, "auto"):
        return "cuda" if torch.cuda.is_available() else "cpu"
    return str(device)


def pick_dtype(spec: VLMSpec, device: str, dtype: str | None) -> torch.dtype:
    """The record's dtype on GPU, float32 on CPU (bf16 matmuls are slow there), unless ``dtype`` is given."""
    name = str(dtype or (spec.dtype if device.startswith("cuda") else "float32"))
    if name not in DTYPES:
        raise ValueError(f"dtype {name!r} for VLM {spec.name!r} is not one of {list(DTYPES)}")
    return DTYPES[name]


def _load_image(path: Path):
    from PIL import Image

    with Image.open(path) as im:
        return im.convert("RGB")


class HFAnswerer:
    """A transformers VLM answering prompts in batches (greedy, left padding)."""

    def __init__(self, spec: VLMSpec, model: torch.nn.Module, processor: Any, *, weights: str, revision: str,
                 device: str, device_map: str | None = None, max_new_tokens: int | None = None,
                 source: str | None = None, notes: dict[str, Any] | None = None) -> None:  # fmt: skip
        self.spec = spec
        self.notes = dict(notes or {})
        self.name = spec.name
        self.model = model.eval()
        self.processor = processor
        self.weights = weights
        self.revision = revision
        self.device = device
        self.device_map = device_map
        self.source = source
        self.max_new_tokens = int(max_new_tokens or spec.generation["max_new_tokens"])
        tok = self.tokenizer
        tok.padding_side = "left"
        if tok.pad_token is None:
            tok.pad_token = tok.eos_token
        self._eos = self._eos_ids()

    @property
    def tokenizer(self) -> Any:
        return getattr(self.processor, "tokenizer", self.processor)

    @property
    def single_image_only(self) -> bool:
        return self.spec.single_image_only

    def _eos_ids(self) -> set[int]:
        ids = getattr(getattr(self.model, "generation_config", None), "eos_token_id", None)
        ids = ids if isinstance(ids, (list, tuple)) else [ids]
        out = {int(i) for i in ids if i is not None}
        if self.tokenizer.eos_token_id is not None:
            out.add(int(self.tokenizer.eos_token_id))
        return out

    def describe(self) -> dict[str, Any]:
        import transformers

        return {"id": self.spec.hf_id, "revision": self.revision, "family": self.spec.family,
                "loader": self.spec.loader, "params_b": self.spec.params_b,
                "dtype": str(self.model.dtype).removeprefix("torch."),
                "weights": self.weights, "max_new_tokens": self.max_new_tokens, "decoding": "greedy",
                "single_image_only": self.spec.single_image_only, "max_images": self.spec.max_images,
                "chat_template": self.spec.chat_template, "prompt_prefix": self.spec.prompt_prefix,
                "processor_kwargs": dict(self.spec.processor_kwargs), "transformers": transformers.__version__,
                "device": self.device, "device_map": self.device_map, "path": self.source, **self.notes}  # fmt: skip

    # -- rendering (family adapters override) ------------------------------------------------------------
    def render(self, prompt: Prompt) -> str:
        """The model's input text of one prompt: its chat template over images first, then the text."""
        content = [{"type": "image"} for _ in prompt.images]
        content.append({"type": "text", "text": self.spec.prompt_prefix + prompt.text})
        messages = [{"role": "user", "content": content}]
        return self.processor.apply_chat_template(messages, add_generation_prompt=True, tokenize=False)

    def inputs(self, prompts: list[Prompt]) -> Any:
        texts = [self.render(p) for p in prompts]
        images = [[_load_image(path) for path in p.images] for p in prompts]
        if not any(images):
            return self.processor(text=texts, padding=True, return_tensors="pt")
        if not all(images):
            raise ValueError("a batch mixes prompts with and without images; batch them apart")
        return self.processor(text=texts, images=images, padding=True, return_tensors="pt")

    @torch.inference_mode()
    def answer(self, prompts: list[Prompt]) -> list[Generation]:
        if not prompts:
            return []
        too_many = [p.idx for p in prompts if self.spec.max_images is not None and len(p.images) > self.spec.max_images]
        if too_many:
            raise ValueError(f"VLM {self.name!r} takes at most {self.spec.max_images} image(s) per prompt; items "
                             f"{too_many[:3]} have more (the evaluation loop filters them)")  # fmt: skip
        start = time.perf_counter()
        batch = self.inputs(prompts)
        target = self.model.device
        batch = {k: (v.to(target) if hasattr(v, "to") else v) for k, v in batch.items() if k != "labels"}
        if "pixel_values" in batch and torch.is_floating_point(batch["pixel_values"]):
            batch["pixel_values"] = batch["pixel_values"].to(self.model.dtype)
        out = self.model.generate(**batch, max_new_tokens=self.max_new_tokens, do_sample=False,
                                  pad_token_id=self.tokenizer.pad_token_id)
        new = out[:, batch["input_ids"].shape[1]:].cpu()
        texts = self.tokenizer.batch_decode(new, skip_special_tokens=True)
        latency = (time.perf_counter() - start) / len(prompts)
        tokens_in = batch["attention_mask"].sum(dim=1).tolist() if "attention_mask" in batch else [None] * len(prompts)
        return [Generation(text=t.strip(), latency_s=latency, tokens_in=int(n_in) if n_in is not None else None,
                           tokens_out=self._count_new(row)) for t, n_in, row in zip(texts, tokens_in, new)]  # fmt: skip

    def _count_new(self, row: torch.Tensor) -> int:
        """Generated tokens up to and including the first end-of-sequence token."""
        for k, tok in enumerate(row.tolist()):
            if tok in self._eos:
                return k + 1
        return int(row.numel())


class PaliGemmaAnswerer(HFAnswerer):
    """PaliGemma (2): no chat template; the text is the task prefix and the prompt, the processor puts the
    image tokens in front."""

    def render(self, prompt: Prompt) -> str:
        return self.spec.prompt_prefix + prompt.text

    def inputs(self, prompts: list[Prompt]) -> Any:
        if any(len(p.images) != 1 for p in prompts):
            raise ValueError(f"VLM {self.name!r} (PaliGemma) takes exactly one image per prompt; blind=true cannot "
                             "remove it: evaluate the set's black_image variant instead")  # fmt: skip
        return super().inputs(prompts)


FAMILY_ADAPTERS: dict[str, type[HFAnswerer]] = {"paligemma": PaliGemmaAnswerer}


def _refuse_remote_code(spec: VLMSpec) -> None:
    if spec.needs_remote_code:
        raise ValueError(
            f"VLM {spec.name!r} ({spec.hf_id}) needs its repo's remote code, which has its own chat() API the generic "
            "adapter does not drive: serve it with vLLM or SGLang and evaluate it through the OpenAI-compatible client"
        )


def load_hf_answerer(spec: VLMSpec, source: str | Path, *, weights: str, revision: str, device: str | None = "auto",
                     dtype: str | None = None, device_map: str | None = None,
                     max_new_tokens: int | None = None, notes: dict[str, Any] | None = None) -> HFAnswerer:  # fmt: skip
    """Load processor and model of ``spec`` from the local directory ``source`` (``notes`` join the manifest)."""
    import transformers

    _refuse_remote_code(spec)
    device = pick_device(device)
    torch_dtype = pick_dtype(spec, device, dtype)
    if device_map is None and device.startswith("cuda") and spec.params_b >= LARGE_MODEL_PARAMS_B:
        device_map = "auto"
    processor = transformers.AutoProcessor.from_pretrained(str(source), **spec.processor_kwargs)
    loader = getattr(transformers, spec.loader)
    model = loader.from_pretrained(str(source), dtype=torch_dtype, device_map=device_map)
    if device_map is None:
        model = model.to(device)
    cls = FAMILY_ADAPTERS.get(spec.family, HFAnswerer)
    return cls(spec, model, processor, weights=weights, revision=revision, device=device, device_map=device_map,
               max_new_tokens=max_new_tokens, source=str(source), notes=notes)  # fmt: skip


def build_hf_answerer(name: str, revision: str | None = None, dtype: str | None = None, device: str | None = "auto",
                      device_map: str | None = None, max_new_tokens: int | None = None,
                      weights_path: str | None = None, allow_download: bool | None = True,
                      processor_kwargs: dict[str, Any] | None = None) -> HFAnswerer:  # fmt: skip
    """The pretrained VLM ``name`` of :mod:`probes.vlm.specs` (``null`` arguments mean the record's value;
    ``processor_kwargs`` replace the record's, e.g. Qwen2-VL's ``{min_pixels: ..., max_pixels: ...}``)."""
    spec = get_spec(str(name))
    if processor_kwargs is not None:
        spec = dataclasses.replace(spec, processor_kwargs=dict(processor_kwargs))
    _refuse_remote_code(spec)  # before any download
    download = True if allow_download is None else bool(allow_download)
    source, resolved = resolve_snapshot(spec, revision, weights_path, download)
    return load_hf_answerer(spec, source, weights="pretrained", revision=resolved, device=device, dtype=dtype,
                            device_map=device_map, max_new_tokens=max_new_tokens)  # fmt: skip
