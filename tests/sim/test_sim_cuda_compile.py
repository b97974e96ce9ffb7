"""The simulator's warp kernels compile for a CUDA GPU (sm_90, H100 / H200) through NVRTC, with no GPU present.

On CPU warp compiles the same kernel source with a host compiler; constructs that only a CPU build accepts
would break the first run on a GPU, so this compiles every simulation module to PTX ahead of time (about 4
minutes on 2 cores, most of it the fused Newton kernel: ``slow``). It checks compilation only; running the
kernels on a GPU is for a machine that has one (issue 13, item 4)."""

from __future__ import annotations

import importlib

import pytest
import warp as wp

from data_gen.sim import KERNEL_MODULES

ARCH = 90


def _nvrtc_archs() -> list[int]:
    wp.init()
    runtime = wp._src.context.runtime
    return list(getattr(runtime, "nvrtc_supported_archs", None) or [])


RENDER_KERNEL_MODULES = ("data_gen.render.projection", "data_gen.render.rgb", "data_gen.render.labels",
                         "data_gen.render.splat_pose", "data_gen.render.shadow_map",
                         "data_gen.render.shading", "data_gen.render.motion_maps")  # fmt: skip
"""The renderer's warp modules (a few seconds each to PTX; they ran on an H200 in the sixteenth session)."""


@pytest.mark.slow
@pytest.mark.parametrize("name", KERNEL_MODULES + RENDER_KERNEL_MODULES)
def test_sim_kernels_compile_to_ptx_for_sm90(name, tmp_path):
    archs = _nvrtc_archs()
    if ARCH not in archs:
        pytest.skip(f"this warp build cannot compile for sm_{ARCH} (NVRTC archs: {archs})")
    module = importlib.import_module(name)
    paths = wp.compile_aot_module(module, arch=ARCH, module_dir=tmp_path, use_ptx=True)
    assert len(paths) == 1
    ptx = paths[0].read_text()
    assert paths[0].suffix == ".ptx" and f".target sm_{ARCH}" in ptx
    assert ".entry" in ptx  # at least one kernel entry point was generated


@pytest.mark.slow
def test_the_blocked_cholesky_compiles_for_the_block_size_it_is_launched_with(tmp_path):
    """``tile_cholesky``'s factorisation is launched with blocks of ``THREADS`` threads, a variant of its module
    apart from the default block size compiled above (warp compiles a module per block size, and MathDx's
    factorisation and products are generated for the block size: ``potrf_..._64``). About 40 s on 2 cores."""
    archs = _nvrtc_archs()
    if ARCH not in archs:
        pytest.skip(f"this warp build cannot compile for sm_{ARCH} (NVRTC archs: {archs})")
    from data_gen.sim import tile_cholesky

    module = wp.get_module(tile_cholesky.__name__)
    default = module.options["block_dim"]
    module.options["block_dim"] = tile_cholesky.THREADS
    try:
        paths = wp.compile_aot_module(tile_cholesky, arch=ARCH, module_dir=tmp_path, use_ptx=True)
    finally:
        module.options["block_dim"] = default
        module.mark_modified()
    source = next(tmp_path.glob("*.cu")).read_text()
    assert f"potrf_32_32_1_{ARCH}_{tile_cholesky.THREADS}_" in source  # the factorisation for 64 threads
    assert ".entry" in paths[0].read_text()
