"""AM-RADIO: no random stand-in exists (its patch generator is remote code), so pretrained=false must
refuse clearly; the wrapper around a loaded model is checked with a STUB model (not RADIO) that records
what it receives."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from probes.backbones import WeightsUnavailableError, build_backbone, get_spec
from probes.backbones.radio import RadioBackbone, RadioUnavailableError


def test_radio_random_weights_are_refused() -> None:
    with pytest.raises(RadioUnavailableError, match="remote code") as err:
        build_backbone("radio", pretrained=False)
    assert "nvidia/RADIO-B" in str(err.value)


def test_radio_weights_path_without_config(tmp_path: Path) -> None:
    with pytest.raises(WeightsUnavailableError, match="config.json"):
        build_backbone("radio", pretrained=True, weights_path=str(tmp_path))


class _StubRadio(torch.nn.Module):
    """Records its input; returns one map per index filled with the index (NOT a RADIO model)."""

    embed_dim = 8

    def __init__(self) -> None:
        super().__init__()
        self.weight = torch.nn.Parameter(torch.ones(1))
        self.seen: torch.Tensor | None = None

    def forward_intermediates(self, x, indices, output_fmt, intermediates_only):
        assert output_fmt == "NCHW" and intermediates_only
        self.seen = x
        b, _, h, w = x.shape
        return [torch.full((b, 8, h // 16, w // 16), float(i)) for i in indices]


def test_radio_wrapper_passes_unnormalised_frames_and_layers() -> None:
    stub = _StubRadio()
    bb = RadioBackbone(
        get_spec("radio"), stub, 8, pretrained=True, layers=[3, 7], image_size=(64, 96), seed=0
    )
    frames = torch.full((2, 3, 32, 48), 0.25)
    maps = bb.features(frames)
    assert [tuple(m.shape) for m in maps] == [(2, 8, 4, 6)] * 2
    assert [m[0, 0, 0, 0].item() for m in maps] == [3.0, 7.0]
    # RADIO normalises inside the model: the wrapper only resizes, values stay in [0, 1]
    assert stub.seen is not None and tuple(stub.seen.shape) == (2, 3, 64, 96)
    torch.testing.assert_close(stub.seen, torch.full_like(stub.seen, 0.25))
    assert bb.mean == pytest.approx((0.48145466, 0.4578275, 0.40821073))
    assert not stub.weight.requires_grad and bb.cache_key()["weights"] == "nvidia/RADIO-B"
