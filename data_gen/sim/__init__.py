"""The simulator (see ``docs/architecture.md``)."""

KERNEL_MODULES = (
    "data_gen.sim.static_scene",
    "data_gen.sim.contact",
    "data_gen.sim.energy.contact_kernels",
    "data_gen.sim.energy.elastic_kernel",
    "data_gen.sim.fused_newton",
    "data_gen.sim.device_newton",
    "data_gen.sim.tile_cholesky",
)
"""The simulator's warp kernel modules (compiled at first use; a fresh machine's empty kernel cache compiles all
of them, ~30 s on the CPU)."""
