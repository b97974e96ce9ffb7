"""Shared pytest fixtures: tiny analytic datasets (see tests/fixtures/synthetic_scene.py)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("WANDB_SILENT", "true")
os.environ.setdefault("HF_HUB_OFFLINE", "1")

from tests.fixtures.synthetic_scene import write_fixture_dataset  # noqa: E402


@pytest.fixture(scope="session")
def synthetic_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Root of a tiny TEST-FIXTURE dataset (analytic boxes, not simulated) with all four splits.

    Each split: 4 sequences of 6 frames at 32x32 in 2 shards; the OOD split
    draws gravity from the OOD range.
    """
    root = tmp_path_factory.mktemp("synthetic_dataset")
    return write_fixture_dataset(root)


@pytest.fixture()
def one_thread():
    """The test machine is shared: one torch intra-op thread avoids oversubscription (restored afterwards)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
