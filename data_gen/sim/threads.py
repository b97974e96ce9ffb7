"""Scoped torch intra-op thread count.

The reduced systems, skinning batches and per-frame splat updates are small
(tens to thousands of rows): on 2 shared cores one thread was ~10x faster than
a contended pool (measured in skinning training and the renderer's per-frame
updates), and a fixed count makes results independent of the caller's
setting. Not safe against other Python threads using torch at the same time.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch


@contextmanager
def torch_threads(num_threads: int) -> Iterator[None]:
    """Temporarily set torch's intra-op thread count (restored on exit)."""
    if num_threads < 1:
        raise ValueError(f"num_threads={num_threads!r} must be >= 1")
    previous = torch.get_num_threads()
    torch.set_num_threads(num_threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
