"""Trainable heads that read frozen-backbone features of K frames and predict a per-pixel map.

Input of every head: a list with one tensor per tapped layer, each
``(B, K, C_l, h_l, w_l)`` (K frames of a clip, oldest first, the last frame is
the target frame). Output: ``(B, out_channels, H, W)`` at the requested target
resolution, by bilinear upsampling of the head's own output.

Temporal fusion (both heads): the K per-frame maps of a layer are
concatenated along channels (``K * C_l`` channels, frame-major), so the first
trainable layer sees every frame at every location and can learn
differences between frames (motion) as well as appearance. This is the
simplest fusion that can express velocity; it costs ``K`` x the first
layer's parameters.

Both heads can start from a constant (``start_from_constant``: output layer
zero, bias = the task's train constant), so training begins at the trivial
baseline instead of at random noise.

* :class:`LinearHead` -- one 1x1 convolution over the last tapped layer
  (``layers="last"``) or over all tapped layers resized to the finest one and
  concatenated (``layers="all"``).
* :class:`DPTHead` -- DPT/Probe3D-style: each layer is reassembled (1x1 conv
  to ``width`` channels, resized to a pyramid of scales 4, 2, 1, 1/2 x the
  feature grid for four taps), then fused coarse-to-fine by residual conv
  units, then a small conv head. Resampling uses bilinear interpolation to
  explicit sizes instead of transposed convolutions, so any feature-grid size
  and any number of taps works.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

_LINEAR_LAYER_MODES = ("last", "all")


def _check_features(feats: list[Tensor], feat_dims: list[int], num_frames: int) -> None:
    if len(feats) != len(feat_dims):
        raise ValueError(f"expected {len(feat_dims)} feature maps (one per tapped layer), got {len(feats)}")
    for i, (f, c) in enumerate(zip(feats, feat_dims)):
        if f.ndim != 5 or f.shape[1] != num_frames or f.shape[2] != c:
            raise ValueError(
                f"feature map {i} must be (B, K={num_frames}, C={c}, h, w), got shape {tuple(f.shape)}"
            )


def _fold_time(f: Tensor) -> Tensor:
    """(B, K, C, h, w) -> (B, K*C, h, w), frame-major channels."""
    b, k, c, h, w = f.shape
    return f.reshape(b, k * c, h, w)


def _validate_common(feat_dims: list[int], num_frames: int, out_channels: int) -> None:
    if len(feat_dims) == 0 or any(int(c) <= 0 for c in feat_dims):
        raise ValueError(f"feat_dims must be a non-empty list of positive ints, got {feat_dims}")
    if num_frames < 1:
        raise ValueError(f"num_frames must be >= 1, got {num_frames}")
    if out_channels < 1:
        raise ValueError(f"out_channels must be >= 1, got {out_channels}")


def count_parameters(module: nn.Module, trainable_only: bool = True) -> int:
    """Number of (trainable) parameters of a module."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad or not trainable_only)


def start_from_constant(layer: nn.Conv2d, bias: Tensor) -> None:
    """Zero the output layer's weights and set its bias: the head then predicts ``bias`` everywhere."""
    bias = torch.as_tensor(bias, dtype=layer.weight.dtype).reshape(-1)
    if bias.numel() != layer.out_channels:
        raise ValueError(
            f"bias must hold {layer.out_channels} values (one per output channel), got {bias.numel()}"
        )
    with torch.no_grad():
        layer.weight.zero_()
        if layer.bias is None:
            raise ValueError("the output layer has no bias to start from")
        layer.bias.copy_(bias.to(layer.bias.device))


class LinearHead(nn.Module):
    """1x1 convolution over time-concatenated features, bilinearly upsampled to the target size."""

    def __init__(
        self, feat_dims: list[int], num_frames: int, out_channels: int, layers: str = "last"
    ) -> None:
        super().__init__()
        _validate_common(feat_dims, num_frames, out_channels)
        if layers not in _LINEAR_LAYER_MODES:
            raise ValueError(f"layers must be one of {_LINEAR_LAYER_MODES}, got {layers!r}")
        self.feat_dims = [int(c) for c in feat_dims]
        self.num_frames = int(num_frames)
        self.layers = layers
        in_ch = num_frames * (self.feat_dims[-1] if layers == "last" else sum(self.feat_dims))
        self.proj = nn.Conv2d(in_ch, out_channels, kernel_size=1)

    def start_from_constant(self, bias: Tensor) -> None:
        """Predict ``bias`` (out_channels,) everywhere until training moves the weights."""
        start_from_constant(self.proj, bias)

    def forward(self, feats: list[Tensor], out_size: tuple[int, int]) -> Tensor:
        _check_features(feats, self.feat_dims, self.num_frames)
        if self.layers == "last":
            x = _fold_time(feats[-1])
        else:
            size = max((f.shape[-2:] for f in feats), key=lambda s: s[0] * s[1])
            x = torch.cat(
                [
                    F.interpolate(_fold_time(f), size=tuple(size), mode="bilinear", align_corners=False)
                    if tuple(f.shape[-2:]) != tuple(size)
                    else _fold_time(f)
                    for f in feats
                ],
                dim=1,
            )
        y = self.proj(x.to(self.proj.weight.dtype))
        return F.interpolate(y, size=tuple(out_size), mode="bilinear", align_corners=False)


class _ResidualConvUnit(nn.Module):
    def __init__(self, width: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(width, width, 3, padding=1)
        self.conv2 = nn.Conv2d(width, width, 3, padding=1)

    def forward(self, x: Tensor) -> Tensor:
        return x + self.conv2(F.relu(self.conv1(F.relu(x))))


class _FusionBlock(nn.Module):
    def __init__(self, width: int) -> None:
        super().__init__()
        self.skip_unit = _ResidualConvUnit(width)
        self.out_unit = _ResidualConvUnit(width)
        self.out_proj = nn.Conv2d(width, width, 1)

    def forward(self, coarse: Tensor | None, skip: Tensor) -> Tensor:
        x = self.skip_unit(skip)
        if coarse is not None:
            x = x + F.interpolate(coarse, size=x.shape[-2:], mode="bilinear", align_corners=False)
        return self.out_proj(self.out_unit(x))


def pyramid_scales(num_layers: int) -> list[float]:
    """Resize factor of each tapped layer (shallow first): 4, 2, 1, 1/2 for four taps; 1 for one."""
    if num_layers == 1:
        return [1.0]
    return [2.0 ** (num_layers - 2 - i) for i in range(num_layers)]


class DPTHead(nn.Module):
    """Multi-layer reassemble + coarse-to-fine fusion head (DPT / Probe3D style), width configurable."""

    def __init__(
        self,
        feat_dims: list[int],
        num_frames: int,
        out_channels: int,
        width: int = 256,
        head_width: int | None = None,
    ) -> None:
        super().__init__()
        _validate_common(feat_dims, num_frames, out_channels)
        if width < 1:
            raise ValueError(f"width must be >= 1, got {width}")
        self.feat_dims = [int(c) for c in feat_dims]
        self.num_frames = int(num_frames)
        self.scales = pyramid_scales(len(feat_dims))
        head_width = head_width or max(width // 2, 1)
        self.reassemble = nn.ModuleList(nn.Conv2d(num_frames * c, width, 1) for c in self.feat_dims)
        self.fusion = nn.ModuleList(_FusionBlock(width) for _ in self.feat_dims)
        self.head = nn.Sequential(
            nn.Conv2d(width, head_width, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(head_width, out_channels, 1),
        )

    def start_from_constant(self, bias: Tensor) -> None:
        """Predict ``bias`` (out_channels,) everywhere until training moves the last layer's weights."""
        last = self.head[-1]
        assert isinstance(last, nn.Conv2d)
        start_from_constant(last, bias)

    def forward(self, feats: list[Tensor], out_size: tuple[int, int]) -> Tensor:
        _check_features(feats, self.feat_dims, self.num_frames)
        dtype = self.reassemble[0].weight.dtype
        h0, w0 = feats[-1].shape[-2:]
        levels = []
        for f, proj, s in zip(feats, self.reassemble, self.scales):
            x = proj(_fold_time(f).to(dtype))
            size = (max(1, round(h0 * s)), max(1, round(w0 * s)))
            if tuple(x.shape[-2:]) != size:
                x = F.interpolate(x, size=size, mode="bilinear", align_corners=False)
            levels.append(x)
        y: Tensor | None = None
        for x, block in zip(reversed(levels), reversed(self.fusion)):
            y = block(y, x)
        assert y is not None
        y = self.head(y)
        return F.interpolate(y, size=tuple(out_size), mode="bilinear", align_corners=False)
