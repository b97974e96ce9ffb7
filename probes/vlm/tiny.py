"""TEST / BENCH FIXTURES: tiny random-weight instances of real VLM architectures, built here, offline.

Each is the real transformers model class (``Qwen2VLForConditionalGeneration``,
``Idefics3ForConditionalGeneration``, ``PaliGemmaForConditionalGeneration``: single-image, no chat template) built from its config class at a tiny size, with the real processor and
image-processor classes and a byte-level tokenizer made locally with the ``tokenizers`` library (256 byte
tokens and the architecture's special tokens, no merges), saved with ``save_pretrained`` and loaded back
through ``AutoProcessor`` / ``AutoModelForImageTextToText`` like a downloaded model. Their weights are RANDOM
(seeded): the manifest says ``weights: random`` and ``fixture: ...``; they exercise the harness (chat
templates, batching, left padding, image tokens, generation) and measure its overhead. They are never a
result about a real model.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from probes.vlm.hf_adapter import HFAnswerer, load_hf_answerer
from probes.vlm.specs import VLMSpec

log = logging.getLogger(__name__)

TINY_VERSION = 1
"""Bump when a tiny build changes (the cache directory name carries it)."""
FIXTURE_NOTE = "TEST FIXTURE: tiny random-weight instance of the architecture; not a trained model"
TINY_MAX_NEW_TOKENS = 8

# Chat templates of the tiny tokenizers (same message layout as the real models': images, then the text).
QWEN_TEMPLATE = (
    "{% for message in messages %}<|im_start|>{{ message['role'] }}\n"
    "{% if message['content'] is string %}{{ message['content'] }}{% else %}{% for c in message['content'] %}"
    "{% if c['type'] == 'image' %}<|vision_start|><|image_pad|><|vision_end|>"
    "{% elif c['type'] == 'text' %}{{ c['text'] }}{% endif %}{% endfor %}{% endif %}<|im_end|>\n{% endfor %}"
    "{% if add_generation_prompt %}<|im_start|>assistant\n{% endif %}"
)
IDEFICS3_TEMPLATE = (
    "<|im_start|>{% for message in messages %}{{ message['role'] | capitalize }}:"
    "{% for c in message['content'] %}{% if c['type'] == 'image' %}<image>"
    "{% elif c['type'] == 'text' %}{{ c['text'] }}{% endif %}{% endfor %}<end_of_utterance>\n{% endfor %}"
    "{% if add_generation_prompt %}Assistant:{% endif %}"
)
TEXT_LAYERS = {"hidden_size": 32, "intermediate_size": 64, "num_hidden_layers": 2, "num_attention_heads": 4,
               "num_key_value_heads": 2, "max_position_embeddings": 4096}  # fmt: skip


def byte_tokenizer(special_tokens: list[str], *, bos: str | None, eos: str, pad: str) -> Any:
    """A byte-level BPE tokenizer without merges (one token per UTF-8 byte) plus ``special_tokens``."""
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers
    from transformers import PreTrainedTokenizerFast

    alphabet = sorted(pre_tokenizers.ByteLevel.alphabet())
    core = Tokenizer(models.BPE(vocab={c: i for i, c in enumerate(alphabet)}, merges=[]))
    core.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    core.decoder = decoders.ByteLevel()
    return PreTrainedTokenizerFast(tokenizer_object=core, bos_token=bos, eos_token=eos, pad_token=pad,
                                   additional_special_tokens=special_tokens)  # fmt: skip


def _qwen2_vl(out: Path, seed: int) -> None:
    from transformers import (
        Qwen2VLConfig,
        Qwen2VLForConditionalGeneration,
        Qwen2VLImageProcessor,
        Qwen2VLProcessor,  # fmt: skip
        Qwen2VLVideoProcessor,
    )

    specials = ["<|endoftext|>", "<|im_start|>", "<|im_end|>", "<|vision_start|>", "<|vision_end|>",
                "<|image_pad|>", "<|video_pad|>"]  # fmt: skip
    tok = byte_tokenizer(specials, bos=None, eos="<|im_end|>", pad="<|endoftext|>")
    ids = dict(zip(specials, tok.convert_tokens_to_ids(specials)))
    # 4 px patches merged 2 x 2: an image of at most 32 x 32 px gives at most 16 visual tokens
    pixels = {"patch_size": 4, "merge_size": 2, "temporal_patch_size": 2}
    processor = Qwen2VLProcessor(
        image_processor=Qwen2VLImageProcessor(**pixels, min_pixels=16 * 16, max_pixels=32 * 32),
        video_processor=Qwen2VLVideoProcessor(**pixels), tokenizer=tok, chat_template=QWEN_TEMPLATE,
    )
    config = Qwen2VLConfig(
        text_config={**TEXT_LAYERS, "vocab_size": len(tok),
                     "rope_scaling": {"type": "mrope", "mrope_section": [2, 1, 1]},
                     "bos_token_id": ids["<|im_start|>"], "eos_token_id": ids["<|im_end|>"],
                     "pad_token_id": ids["<|endoftext|>"]},
        vision_config={"depth": 2, "embed_dim": 32, "hidden_size": 32, "num_heads": 4, "mlp_ratio": 2,
                       "patch_size": 4, "spatial_merge_size": 2, "temporal_patch_size": 2, "in_chans": 3},
        image_token_id=ids["<|image_pad|>"], video_token_id=ids["<|video_pad|>"],
        vision_start_token_id=ids["<|vision_start|>"], vision_end_token_id=ids["<|vision_end|>"],
    )  # fmt: skip
    _save(Qwen2VLForConditionalGeneration, config, processor, out, seed, eos=ids["<|im_end|>"],
          pad=ids["<|endoftext|>"])


def _idefics3(out: Path, seed: int) -> None:
    from transformers import (
        Idefics3Config,
        Idefics3ForConditionalGeneration,
        Idefics3ImageProcessor,
        Idefics3Processor,
    )

    specials = ["<|endoftext|>", "<|im_start|>", "<end_of_utterance>", "<fake_token_around_image>", "<image>",
                "<global-img>"] + [f"<row_{i + 1}_col_{j + 1}>" for i in range(6) for j in range(6)]  # fmt: skip
    tok = byte_tokenizer(specials, bos="<|im_start|>", eos="<end_of_utterance>", pad="<|endoftext|>")
    ids = dict(zip(specials, tok.convert_tokens_to_ids(specials)))
    # one 32 px tile per image (no splitting), 8 px patches, pixel shuffle 2: (32 / 8)^2 / 2^2 = 4 image tokens
    processor = Idefics3Processor(
        image_processor=Idefics3ImageProcessor(size={"longest_edge": 32}, max_image_size={"longest_edge": 32},
                                               do_image_splitting=False),
        tokenizer=tok, image_seq_len=4, chat_template=IDEFICS3_TEMPLATE,
    )  # fmt: skip
    config = Idefics3Config(
        text_config={**TEXT_LAYERS, "model_type": "llama", "vocab_size": len(tok), "bos_token_id": ids["<|im_start|>"],
                     "eos_token_id": ids["<end_of_utterance>"], "pad_token_id": ids["<|endoftext|>"]},
        vision_config={"hidden_size": 32, "intermediate_size": 64, "num_hidden_layers": 2, "num_attention_heads": 4,
                       "image_size": 32, "patch_size": 8},
        image_token_id=ids["<image>"], scale_factor=2, pad_token_id=ids["<|endoftext|>"],
    )  # fmt: skip
    _save(Idefics3ForConditionalGeneration, config, processor, out, seed, eos=ids["<end_of_utterance>"],
          pad=ids["<|endoftext|>"])


def _paligemma(out: Path, seed: int) -> None:
    from transformers import (
        PaliGemmaConfig,
        PaliGemmaForConditionalGeneration,
        PaliGemmaProcessor,
        SiglipImageProcessor,
    )

    specials = ["<pad>", "<bos>", "<eos>", "<image>"]
    tok = byte_tokenizer(specials, bos="<bos>", eos="<eos>", pad="<pad>")
    # one 32 px image, 8 px patches: (32 / 8)^2 = 16 image tokens; the processor adds PaliGemma's 1024 location
    # and 128 segmentation tokens to the tokenizer, so the vocabulary is counted after it is built
    image_processor = SiglipImageProcessor(size={"height": 32, "width": 32})
    image_processor.image_seq_length = 16
    processor = PaliGemmaProcessor(image_processor=image_processor, tokenizer=tok)
    ids = dict(zip(specials, tok.convert_tokens_to_ids(specials)))
    config = PaliGemmaConfig(
        text_config={**TEXT_LAYERS, "model_type": "gemma2", "head_dim": 8, "vocab_size": len(tok),
                     "bos_token_id": ids["<bos>"], "eos_token_id": ids["<eos>"], "pad_token_id": ids["<pad>"]},
        vision_config={"hidden_size": 32, "intermediate_size": 64, "num_hidden_layers": 2, "num_attention_heads": 4,
                       "image_size": 32, "patch_size": 8},
        image_token_index=ids["<image>"], projection_dim=32, hidden_size=32,
    )  # fmt: skip
    _save(PaliGemmaForConditionalGeneration, config, processor, out, seed, eos=ids["<eos>"], pad=ids["<pad>"])


def _save(model_cls: Any, config: Any, processor: Any, out: Path, seed: int, *, eos: int, pad: int) -> None:
    from transformers import GenerationConfig

    state = torch.random.get_rng_state()
    torch.manual_seed(seed)
    try:
        model = model_cls(config).eval()
    finally:
        torch.random.set_rng_state(state)
    model.generation_config = GenerationConfig(eos_token_id=eos, pad_token_id=pad, do_sample=False)
    model.save_pretrained(out)
    processor.save_pretrained(out)


TINY_BUILDERS: dict[str, Callable[[Path, int], None]] = {"qwen2_vl": _qwen2_vl, "idefics3": _idefics3,
                                                         "paligemma": _paligemma}
TINY_ARCHS: tuple[str, ...] = tuple(TINY_BUILDERS)
TINY_SPECS: dict[str, VLMSpec] = {
    "qwen2_vl": VLMSpec("tiny_qwen2_vl", "newtphys/tiny-random-qwen2_vl", "qwen2_vl", "AutoModelForImageTextToText",
                        1e-4, dtype="float32", video=True, generation={"max_new_tokens": TINY_MAX_NEW_TOKENS},
                        description=FIXTURE_NOTE),
    "idefics3": VLMSpec("tiny_idefics3", "newtphys/tiny-random-idefics3", "idefics3", "AutoModelForImageTextToText",
                        1e-4, dtype="float32", generation={"max_new_tokens": TINY_MAX_NEW_TOKENS},
                        description=FIXTURE_NOTE),
    "paligemma": VLMSpec("tiny_paligemma", "newtphys/tiny-random-paligemma", "paligemma",
                         "AutoModelForImageTextToText", 1e-4, dtype="float32", multi_image=False, max_images=1,
                         chat_template="none", prompt_prefix="answer en ",
                         generation={"max_new_tokens": TINY_MAX_NEW_TOKENS}, description=FIXTURE_NOTE),
}  # fmt: skip
"""Records of the fixtures (``params_b`` nominal; the manifest gets the counted parameters)."""


def default_cache_dir() -> Path:
    """``$NEWTPHYS_TINY_VLM_DIR``, else ``~/.cache/newtphys/tiny_vlm``."""
    env = os.environ.get("NEWTPHYS_TINY_VLM_DIR")
    return Path(env).expanduser() if env else Path("~/.cache/newtphys/tiny_vlm").expanduser()


def tiny_model_dir(arch: str, seed: int = 0, cache_dir: Path | str | None = None) -> Path:
    """Directory of the saved tiny ``arch`` (built on first use, atomically: a temporary directory renamed)."""
    if arch not in TINY_BUILDERS:
        raise KeyError(f"unknown tiny VLM architecture {arch!r}; valid: {', '.join(TINY_ARCHS)}")
    import transformers

    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    out = root / f"{arch}-seed{int(seed)}-v{TINY_VERSION}-tf{transformers.__version__}"
    if (out / "config.json").is_file():
        return out
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{arch}-", dir=root))
    try:
        TINY_BUILDERS[arch](tmp, int(seed))
        try:
            tmp.rename(out)
        except OSError:  # built concurrently by another process: keep theirs
            if not (out / "config.json").is_file():
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    log.warning("built tiny RANDOM-weight %s VLM fixture in %s", arch, out)
    return out


def build_tiny_answerer(name: str, seed: int = 0, cache_dir: str | None = None, device: str | None = "cpu",
                        max_new_tokens: int | None = None) -> HFAnswerer:  # fmt: skip
    """The tiny random-weight architecture ``name`` (``qwen2_vl`` or ``tiny_qwen2_vl``, ... of
    :data:`TINY_ARCHS`) behind the generic adapter."""
    arch = str(name).removeprefix("tiny_")
    source = tiny_model_dir(arch, seed, cache_dir)
    spec = TINY_SPECS[arch]
    answerer = load_hf_answerer(spec, source, weights="random", revision=f"tiny-v{TINY_VERSION}", device=device,
                                dtype="float32", max_new_tokens=max_new_tokens,
                                notes={"fixture": FIXTURE_NOTE, "seed": int(seed), "architecture": arch})  # fmt: skip
    answerer.notes["parameters"] = int(sum(p.numel() for p in answerer.model.parameters()))
    return answerer
