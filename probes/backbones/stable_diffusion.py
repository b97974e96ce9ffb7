"""Stable Diffusion UNet features (diffusers ``UNet2DConditionModel`` + ``AutoencoderKL``).

Pipeline per frame batch (DIFT-style):

1. pixels in [-1, 1] (mean = std = 0.5 on RGB in [0, 1]) -> VAE encoder -> latent
   distribution mean x ``scaling_factor`` (0.18215 for SD 1.5): (B, 4, H/8, W/8);
2. noised to ``timestep`` t (default 261) with the DDPM schedule:
   ``sqrt(abar_t) z + sqrt(1 - abar_t) eps``; ``eps`` is drawn ONCE per latent shape
   from ``noise_seed`` and shared by every frame, so a frame's features never
   depend on its batch neighbours or on call order;
3. one UNet pass conditioned on the empty-prompt text embedding (CLIP text
   encoder output of ``""``; with ``pretrained=false`` the text encoder weights
   are absent and a ZERO embedding of the right width (77 x cross_attention_dim)
   is used); forward hooks record the outputs of the tapped up blocks and the
   pass stops after the last tapped block;
4. every tapped map is resized bilinearly to the latent grid (H/8, W/8), so the
   effective stride of all returned maps is 8 px (``patch_size`` = 8).

Up blocks of SD 1.5 output 1280, 1280, 640, 320 channels at strides 32, 16, 8, 8 px.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import torch
import torch.nn.functional as F

from probes.backbones.base import Backbone, seeded_init, warn_random_weights
from probes.backbones.specs import BackboneSpec
from probes.backbones.weights import resolve_hf_snapshot

SD_REQUIRED_FILES: tuple[str, ...] = (
    "unet/config.json",
    "vae/config.json",
    "scheduler/scheduler_config.json",
    "text_encoder/config.json",
    "tokenizer/tokenizer_config.json",
)
TEXT_TOKENS = 77  # CLIP text context length used by SD


class _StopForward(Exception):
    """Raised by the last tapped up-block hook to skip the rest of the UNet."""


class StableDiffusionBackbone(Backbone):
    """Noised-latent UNet up-block features."""

    def __init__(
        self,
        spec: BackboneSpec,
        *,
        unet: torch.nn.Module,
        vae: torch.nn.Module,
        alphas_cumprod: torch.Tensor,
        text_embedding: torch.Tensor,
        timestep: int,
        noise_seed: int,
        prompt: str,
        **kwargs: Any,
    ) -> None:
        up_channels = list(reversed(unet.config.block_out_channels))
        feat_dims = [int(up_channels[i]) for i in kwargs["layers"]]
        num_steps = int(alphas_cumprod.shape[0])
        if not 0 <= timestep < num_steps:
            raise ValueError(
                f"timestep={timestep} for backbone {spec.name!r} must be in [0, {num_steps - 1}]"
            )
        if noise_seed < 0:
            raise ValueError(f"noise_seed must be >= 0; got {noise_seed}")
        extra = {"timestep": int(timestep), "noise_seed": int(noise_seed), "prompt": prompt, "latent": "mean"}
        super().__init__(
            spec, feat_dims=feat_dims, extra_key={**extra, **kwargs.pop("extra_key", {})}, **kwargs
        )
        self.unet = unet
        self.vae = vae
        self.timestep = int(timestep)
        self.noise_seed = int(noise_seed)
        self.scaling_factor = float(vae.config.scaling_factor)
        abar = float(alphas_cumprod[self.timestep])
        self.signal_scale = abar**0.5
        self.noise_scale = (1.0 - abar) ** 0.5
        self.register_buffer("text_embedding", text_embedding.detach().float(), persistent=False)
        self.freeze()

    def latents(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised pixels in [-1, 1] (B, 3, H, W) -> scaled latent means (B, 4, H/8, W/8)."""
        return self.vae.encode(x).latent_dist.mean * self.scaling_factor

    def noise(self, shape: torch.Size) -> torch.Tensor:
        """The fixed noise of one latent (C, h, w), drawn from ``noise_seed``."""
        generator = torch.Generator().manual_seed(self.noise_seed)
        return torch.randn(tuple(shape), generator=generator).to(self._mean.device)

    def _tapped_maps(self, x: torch.Tensor) -> list[torch.Tensor]:
        z = self.latents(x)
        noisy = self.signal_scale * z + self.noise_scale * self.noise(z.shape[1:]).unsqueeze(0)
        captured: dict[int, torch.Tensor] = {}
        last = self.layers[-1]

        def hook_for(index: int) -> Callable[[torch.nn.Module, Any, torch.Tensor], None]:
            def hook(_module: torch.nn.Module, _inputs: Any, output: torch.Tensor) -> None:
                captured[index] = output
                if index == last:
                    raise _StopForward

            return hook

        handles = [self.unet.up_blocks[i].register_forward_hook(hook_for(i)) for i in self.layers]
        t = torch.full((x.shape[0],), self.timestep, dtype=torch.long, device=x.device)
        context = self.text_embedding.expand(x.shape[0], -1, -1)
        try:
            self.unet(noisy, t, encoder_hidden_states=context)
        except _StopForward:
            pass
        finally:
            for handle in handles:
                handle.remove()
        grid = z.shape[-2:]
        return [
            F.interpolate(captured[i], size=grid, mode="bilinear", align_corners=False) for i in self.layers
        ]


def _alphas_cumprod(scheduler_config: dict[str, Any]) -> torch.Tensor:
    from diffusers import DDPMScheduler

    return DDPMScheduler(**scheduler_config).alphas_cumprod.float()


def _empty_prompt_embedding(local_dir: str, prompt: str) -> torch.Tensor:
    """CLIP text-encoder output (1, 77, D) of ``prompt`` (SD's conditioning), from the local snapshot."""
    from transformers import CLIPTextModel, CLIPTokenizer

    tokenizer = CLIPTokenizer.from_pretrained(local_dir, subfolder="tokenizer", local_files_only=True)
    encoder = CLIPTextModel.from_pretrained(local_dir, subfolder="text_encoder", local_files_only=True)
    ids = tokenizer(
        [prompt],
        padding="max_length",
        max_length=tokenizer.model_max_length,
        truncation=True,
        return_tensors="pt",
    ).input_ids
    with torch.no_grad():
        return encoder(ids)[0]


def _drop_decoder(vae: torch.nn.Module) -> torch.nn.Module:
    """Only the VAE encoder is used; free the decoder's memory."""
    vae.decoder = torch.nn.Identity()
    vae.post_quant_conv = torch.nn.Identity()
    return vae


def build_stable_diffusion(
    spec: BackboneSpec,
    *,
    pretrained: bool,
    layers: list[int],
    image_size: tuple[int, int],
    seed: int,
    weights_path: str | os.PathLike[str] | None = None,
    allow_download: bool = True,
    arch_overrides: dict[str, Any] | None = None,
    timestep: int | None = None,
    noise_seed: int | None = None,
    prompt: str | None = None,
) -> StableDiffusionBackbone:
    """SD UNet features; ``arch_overrides`` may hold reduced ``unet`` / ``vae`` diffusers configs (tests)."""
    from diffusers import AutoencoderKL, DDPMScheduler, UNet2DConditionModel

    timestep = int(spec.extra["timestep"] if timestep is None else timestep)
    noise_seed = int(spec.extra["noise_seed"] if noise_seed is None else noise_seed)
    prompt = str(spec.extra["prompt"] if prompt is None else prompt)
    overrides = dict(arch_overrides or {})
    unknown = sorted(set(overrides) - {"unet", "vae", "scheduler"})
    if unknown:
        raise ValueError(
            f"arch_overrides keys {unknown} for 'sd' are unknown; allowed: ['scheduler', 'unet', 'vae']"
        )
    if pretrained:
        local_dir = str(
            resolve_hf_snapshot(spec.name, spec.hf_repo, SD_REQUIRED_FILES, weights_path, allow_download)
        )
        unet = UNet2DConditionModel.from_pretrained(local_dir, subfolder="unet", local_files_only=True)
        vae = AutoencoderKL.from_pretrained(local_dir, subfolder="vae", local_files_only=True)
        alphas = DDPMScheduler.from_pretrained(local_dir, subfolder="scheduler").alphas_cumprod.float()
        text = _empty_prompt_embedding(local_dir, prompt)
    else:
        warn_random_weights(spec.name, seed)
        unet_cfg = {**spec.arch_kwargs["unet"], **overrides.get("unet", {})}
        vae_cfg = {**spec.arch_kwargs["vae"], **overrides.get("vae", {})}
        with seeded_init(seed):
            unet = UNet2DConditionModel(**unet_cfg)
            vae = AutoencoderKL(**vae_cfg)
        alphas = _alphas_cumprod({**spec.arch_kwargs["scheduler"], **overrides.get("scheduler", {})})
        text = torch.zeros(1, TEXT_TOKENS, int(unet.config.cross_attention_dim))
    return StableDiffusionBackbone(
        spec,
        unet=unet,
        vae=_drop_decoder(vae),
        alphas_cumprod=alphas,
        text_embedding=text,
        timestep=timestep,
        noise_seed=noise_seed,
        prompt=prompt,
        pretrained=pretrained,
        layers=layers,
        image_size=image_size,
        seed=seed,
        extra_key={
            "arch_overrides": overrides,
            "text_embedding": "clip-text" if pretrained else "zeros (text encoder weights absent)",
        },
    )
