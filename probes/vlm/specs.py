"""VLM config records: every evaluated Hugging Face model declared as data.

One :class:`VLMSpec` per registry name; :func:`probes.vlm.hf_adapter.build_hf_answerer` reads a record and
builds the generic transformers adapter (or a family adapter where a family needs code). Adding a checkpoint
of a known family is adding one entry here and a YAML ``newtphys/conf/vlm/<name>.yaml`` naming it.

Ids are the Hugging Face repos of the transformers-native checkpoints (``-hf`` repos where a family has both,
e.g. InternVL3, LLaVA); ``params_b`` is the model card's parameter count in billions (it sizes the
throughput projection of ``bench/bench_vlm.py`` and picks ``device_map="auto"`` for the large ones).
Models whose repo needs ``trust_remote_code`` are listed with ``needs_remote_code=True``: the generic adapter
refuses them (their remote code has its own ``chat()`` API); serve them with vLLM / SGLang and use the
OpenAI-compatible client instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

LOADERS: tuple[str, ...] = ("AutoModelForImageTextToText", "AutoModelForCausalLM", "AutoModel")
"""transformers auto classes a record may name."""
CHAT_TEMPLATES: tuple[str, ...] = ("model", "none")
"""``model``: the processor's chat template; ``none``: no template (PaliGemma: a task prefix, images implied)."""
DEFAULT_GENERATION: dict[str, Any] = {"max_new_tokens": 16}
"""Greedy decoding; 16 new tokens leave room for "The answer is (B)." without paying for essays."""


@dataclass(frozen=True)
class VLMSpec:
    """Everything that declares one vision-language model.

    Attributes:
        name: registry name (``vlm=<name>`` on the command line).
        hf_id: Hugging Face repo id of the weights, processor and chat template.
        family: architecture family (``qwen2_vl``, ``qwen2_5_vl``, ``llava_onevision``, ``llava_next``,
            ``llava``, ``internvl``, ``idefics3``, ``smolvlm``, ``paligemma``, ``gemma3``, ``mllama``, ...);
            picks a family adapter when one exists (:data:`probes.vlm.hf_adapter.FAMILY_ADAPTERS`).
        loader: transformers auto class that loads the weights (one of :data:`LOADERS`).
        params_b: parameters, billions (model card).
        dtype: torch dtype on GPU (``bfloat16``); on CPU the adapter uses float32 unless told otherwise.
        image: takes images at all.
        multi_image: takes several images in one prompt (else it gets only ``single`` items).
        video: takes video input (multi-frame items are still given as images, the paper's protocol).
        max_images: most images one prompt may carry (None: no limit known); items with more are skipped.
        chat_template: ``model`` (the processor's) or ``none`` (see :data:`CHAT_TEMPLATES`).
        prompt_prefix: text put before the protocol prompt (PaliGemma's task prefix).
        processor_kwargs: passed to ``AutoProcessor.from_pretrained`` (e.g. Qwen's pixel budget).
        generation: ``generate()`` settings (greedy; ``max_new_tokens``).
        needs_remote_code: the repo needs ``trust_remote_code`` (the generic adapter refuses it).
        gated: the repo asks for accepted terms (a token with access) before download.
        description: one line for reports.
    """

    name: str
    hf_id: str
    family: str
    loader: str
    params_b: float
    dtype: str = "bfloat16"
    image: bool = True
    multi_image: bool = True
    video: bool = False
    max_images: int | None = None
    chat_template: str = "model"
    prompt_prefix: str = ""
    processor_kwargs: dict[str, Any] = field(default_factory=dict)
    generation: dict[str, Any] = field(default_factory=lambda: dict(DEFAULT_GENERATION))
    needs_remote_code: bool = False
    gated: bool = False
    description: str = ""

    def __post_init__(self) -> None:
        if self.loader not in LOADERS:
            raise ValueError(f"VLM spec {self.name!r}: loader {self.loader!r} is not one of {list(LOADERS)}")
        if self.chat_template not in CHAT_TEMPLATES:
            raise ValueError(
                f"VLM spec {self.name!r}: chat_template {self.chat_template!r} is not one of {list(CHAT_TEMPLATES)}"
            )
        if self.params_b <= 0:
            raise ValueError(f"VLM spec {self.name!r}: params_b must be > 0 (billions), got {self.params_b}")
        if self.max_images is not None and self.max_images < 1:
            raise ValueError(f"VLM spec {self.name!r}: max_images must be >= 1 or None, got {self.max_images}")
        if not self.multi_image and self.max_images not in (None, 1):
            raise ValueError(f"VLM spec {self.name!r}: a single-image model has max_images 1, got {self.max_images}")
        if int(self.generation.get("max_new_tokens", 0)) < 1:
            raise ValueError(f"VLM spec {self.name!r}: generation.max_new_tokens must be >= 1")

    @property
    def single_image_only(self) -> bool:
        """True when the model gets only the set's ``single`` items (the protocol)."""
        return not self.multi_image


IT2T = "AutoModelForImageTextToText"
def _qwen(name: str, hf_id: str, family: str, params_b: float, description: str) -> VLMSpec:
    # the processor's own pixel budget (the repo's preprocessor config); vlm.processor_kwargs overrides it
    return VLMSpec(name, hf_id, family, IT2T, params_b, video=True, description=description)


def _specs() -> dict[str, VLMSpec]:
    rows = [
        # Qwen2-VL / Qwen2.5-VL (multi-image, video)
        _qwen("qwen2_vl_2b", "Qwen/Qwen2-VL-2B-Instruct", "qwen2_vl", 2.2, "Qwen2-VL 2B Instruct"),
        _qwen("qwen2_vl_7b", "Qwen/Qwen2-VL-7B-Instruct", "qwen2_vl", 8.3, "Qwen2-VL 7B Instruct"),
        _qwen("qwen2_vl_72b", "Qwen/Qwen2-VL-72B-Instruct", "qwen2_vl", 73.4, "Qwen2-VL 72B Instruct"),
        _qwen("qwen2_5_vl_3b", "Qwen/Qwen2.5-VL-3B-Instruct", "qwen2_5_vl", 3.8, "Qwen2.5-VL 3B Instruct"),
        _qwen("qwen2_5_vl_7b", "Qwen/Qwen2.5-VL-7B-Instruct", "qwen2_5_vl", 8.3, "Qwen2.5-VL 7B Instruct"),
        _qwen("qwen2_5_vl_32b", "Qwen/Qwen2.5-VL-32B-Instruct", "qwen2_5_vl", 33.5, "Qwen2.5-VL 32B Instruct"),
        _qwen("qwen2_5_vl_72b", "Qwen/Qwen2.5-VL-72B-Instruct", "qwen2_5_vl", 73.4, "Qwen2.5-VL 72B Instruct"),
        # LLaVA-OneVision (multi-image, video) / LLaVA-NeXT and LLaVA-1.5 (trained on single images)
        VLMSpec("llava_onevision_0_5b", "llava-hf/llava-onevision-qwen2-0.5b-ov-hf", "llava_onevision", IT2T, 0.9,
                video=True, description="LLaVA-OneVision Qwen2 0.5B (ov)"),
        VLMSpec("llava_onevision_7b", "llava-hf/llava-onevision-qwen2-7b-ov-hf", "llava_onevision", IT2T, 8.0,
                video=True, description="LLaVA-OneVision Qwen2 7B (ov)"),
        VLMSpec("llava_onevision_72b", "llava-hf/llava-onevision-qwen2-72b-ov-hf", "llava_onevision", IT2T, 73.2,
                video=True, description="LLaVA-OneVision Qwen2 72B (ov)"),
        VLMSpec("llava_next_mistral_7b", "llava-hf/llava-v1.6-mistral-7b-hf", "llava_next", IT2T, 7.6,
                multi_image=False, max_images=1, description="LLaVA-NeXT (1.6) Mistral 7B; single-image"),
        VLMSpec("llava_next_34b", "llava-hf/llava-v1.6-34b-hf", "llava_next", IT2T, 34.8,
                multi_image=False, max_images=1, description="LLaVA-NeXT (1.6) Yi 34B; single-image"),
        VLMSpec("llava_1_5_7b", "llava-hf/llava-1.5-7b-hf", "llava", IT2T, 7.1,
                multi_image=False, max_images=1, description="LLaVA-1.5 7B; single-image"),
        # InternVL3, transformers-native "-hf" conversions (multi-image, video)
        VLMSpec("internvl3_1b", "OpenGVLab/InternVL3-1B-hf", "internvl", IT2T, 0.9, video=True,
                description="InternVL3 1B (transformers-native conversion)"),
        VLMSpec("internvl3_2b", "OpenGVLab/InternVL3-2B-hf", "internvl", IT2T, 2.1, video=True,
                description="InternVL3 2B (transformers-native conversion)"),
        VLMSpec("internvl3_8b", "OpenGVLab/InternVL3-8B-hf", "internvl", IT2T, 7.9, video=True,
                description="InternVL3 8B (transformers-native conversion)"),
        VLMSpec("internvl3_14b", "OpenGVLab/InternVL3-14B-hf", "internvl", IT2T, 15.1, video=True,
                description="InternVL3 14B (transformers-native conversion)"),
        VLMSpec("internvl3_38b", "OpenGVLab/InternVL3-38B-hf", "internvl", IT2T, 38.4, video=True,
                description="InternVL3 38B (transformers-native conversion)"),
        VLMSpec("internvl3_78b", "OpenGVLab/InternVL3-78B-hf", "internvl", IT2T, 78.4, video=True,
                description="InternVL3 78B (transformers-native conversion)"),
        # Idefics3 / SmolVLM (multi-image; SmolVLM2 also video)
        VLMSpec("idefics3_8b", "HuggingFaceM4/Idefics3-8B-Llama3", "idefics3", IT2T, 8.5,
                description="Idefics3 8B (Llama 3.1)"),
        VLMSpec("smolvlm_256m", "HuggingFaceTB/SmolVLM-256M-Instruct", "smolvlm", IT2T, 0.26,
                description="SmolVLM 256M Instruct"),
        VLMSpec("smolvlm_500m", "HuggingFaceTB/SmolVLM-500M-Instruct", "smolvlm", IT2T, 0.51,
                description="SmolVLM 500M Instruct"),
        VLMSpec("smolvlm_2b", "HuggingFaceTB/SmolVLM-Instruct", "smolvlm", IT2T, 2.2,
                description="SmolVLM 2B Instruct"),
        VLMSpec("smolvlm2_2b", "HuggingFaceTB/SmolVLM2-2.2B-Instruct", "smolvlm", IT2T, 2.2, video=True,
                description="SmolVLM2 2.2B Instruct"),
        # PaliGemma 2 mix: no chat template, a task prefix, one image
        VLMSpec("paligemma2_3b", "google/paligemma2-3b-mix-448", "paligemma", IT2T, 3.0, multi_image=False,
                max_images=1, chat_template="none", prompt_prefix="answer en ", gated=True,
                description="PaliGemma 2 3B mix 448 px; single-image, no chat template"),
        VLMSpec("paligemma2_10b", "google/paligemma2-10b-mix-448", "paligemma", IT2T, 9.7, multi_image=False,
                max_images=1, chat_template="none", prompt_prefix="answer en ", gated=True,
                description="PaliGemma 2 10B mix 448 px; single-image, no chat template"),
        # Gemma 3 (multi-image) and Llama 3.2 Vision (one image per prompt)
        VLMSpec("gemma3_4b", "google/gemma-3-4b-it", "gemma3", IT2T, 4.3, gated=True,
                description="Gemma 3 4B instruction-tuned"),
        VLMSpec("gemma3_27b", "google/gemma-3-27b-it", "gemma3", IT2T, 27.4, gated=True,
                description="Gemma 3 27B instruction-tuned"),
        VLMSpec("llama3_2_11b_vision", "meta-llama/Llama-3.2-11B-Vision-Instruct", "mllama", IT2T, 10.7,
                multi_image=False, max_images=1, gated=True,
                description="Llama 3.2 11B Vision Instruct; single-image"),
        # need their repos' remote code: listed for the record, served through the OpenAI-compatible client
        VLMSpec("internvl2_5_8b", "OpenGVLab/InternVL2_5-8B", "internvl_chat", "AutoModel", 8.1,
                needs_remote_code=True, description="InternVL2.5 8B (remote code; serve with vLLM)"),
        VLMSpec("phi3_5_vision", "microsoft/Phi-3.5-vision-instruct", "phi3_v", "AutoModelForCausalLM", 4.2,
                needs_remote_code=True, description="Phi-3.5-vision 4.2B (remote code; serve with vLLM)"),
        VLMSpec("minicpm_v2_6", "openbmb/MiniCPM-V-2_6", "minicpmv", "AutoModel", 8.1, video=True,
                needs_remote_code=True, description="MiniCPM-V 2.6 8B (remote code; serve with vLLM)"),
    ]  # fmt: skip
    specs: dict[str, VLMSpec] = {}
    for spec in rows:
        if spec.name in specs:
            raise ValueError(f"duplicate VLM spec name {spec.name!r}")
        specs[spec.name] = spec
    return specs


SPECS: dict[str, VLMSpec] = _specs()
VLM_NAMES: tuple[str, ...] = tuple(sorted(SPECS))


def get_spec(name: str) -> VLMSpec:
    """The record of VLM ``name``; an unknown name raises ``KeyError`` listing the valid ones."""
    if name not in SPECS:
        raise KeyError(f"unknown VLM name {name!r}; valid names: {', '.join(VLM_NAMES)}")
    return SPECS[name]
