"""Where a simulation spends its wall-clock time: timers around named methods and around every warp launch.

A sampling profiler (py-spy) sees a warp launch as one Python line, and a per-line profiler slows the small
calls it measures by several times. :class:`SectionTimer` instead wraps a chosen list of methods (by default the
simulator's step, its broad phase, its solves and its records, :data:`DEFAULT_SECTIONS`) with a
``time.perf_counter`` pair each, and every ``warp.launch`` / recorded ``warp.Launch.launch`` with one per kernel.
The times are inclusive (a section's time contains the sections it calls), so the shares of a table do not add
up to 100 %: read them as "how much of the run sits under this function"; the own time of a section is its
inclusive time less that of the timed sections it called (one thread at a time: the open sections are one stack).

    from data_gen.sim.section_timer import SectionTimer

    with SectionTimer() as timer:
        result = simulator.run(26, fps=25.0)
    print(timer.table())

The wrappers are installed on the classes for the ``with`` block only (every run in the process, in any thread,
is timed meanwhile) and removed on exit, also when the block raises. Each wrapper costs about a microsecond a
call: a table of a run with many tiny calls reads a few per cent high.
"""

from __future__ import annotations

import functools
import importlib
import sys
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass

import warp as wp

# (module, class or None for a module-level function, method) of the sections timed by default; the first is
# the root of the table's shares
DEFAULT_SECTIONS: tuple[tuple[str, str | None, str], ...] = (
    ("data_gen.sim.world", "Simulator", "run"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "step"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_step_candidates"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_island_substeps"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_solve_rigid_substeps"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_launch_rigid_parts"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_solve_group"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_record_substep_statistics"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_record_substep_sphere_forces"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_record_group_forces"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_record_sleeping_contacts"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "_update_sleep"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "energies"),
    ("data_gen.sim.solver", "ImplicitEulerSolver", "cubature_contacts"),
    ("data_gen.sim.contacts", "BroadPhase", "candidates"),
    ("data_gen.sim.contact", "PairFinder", "find"),
    ("data_gen.sim.fused_newton", "FusedNewton", "solve_substeps"),
    ("data_gen.sim.fused_newton", "FusedNewton", "solve_split"),
    ("data_gen.sim.step_objective", "StepObjective", "evaluate"),
    ("data_gen.sim.newton", None, "cholesky_direction"),
    ("data_gen.sim.lapack", "CholeskyDirections", "solve_suited"),
    ("data_gen.sim.recording", "FrameRecorder", "record"),
)


@dataclass(frozen=True)
class Section:
    """One timed section: its name (``Class.method``, ``function`` or ``launch:<kernel>``), inclusive wall time
    (s), number of calls, share of the root section's time, and its own time (s): the inclusive time less that of
    the timed sections it called (what is left to find in it)."""

    name: str
    seconds: float
    calls: int
    share: float
    own_seconds: float


class SectionTimer:
    """Inclusive wall-clock time and call count of named methods and of every warp kernel launch.

    Args:
        sections: (module, class or None for a module-level function, method) triples; the first is the root
            (100 %). Default: :data:`DEFAULT_SECTIONS`.
        kernels: also time every ``warp.launch`` and ``warp.Launch.launch``, one section per kernel.

    Raises ValueError naming a section that does not exist (a method renamed since the list was written).
    """

    def __init__(
        self, sections: Iterable[tuple[str, str | None, str]] | None = None, kernels: bool = True
    ) -> None:
        self.sections = tuple(DEFAULT_SECTIONS if sections is None else sections)
        if not self.sections:
            raise ValueError("SectionTimer: no sections to time")
        self.kernels = kernels
        self.seconds: Counter[str] = Counter()  # inclusive
        self.own_seconds: Counter[str] = Counter()  # exclusive: less the timed sections called from it
        self.calls: Counter[str] = Counter()
        self._open_children: list[float] = []  # per open call: time spent in the sections it called
        self._installed: list[tuple[object, str, object]] = []  # (owner, attribute, original)
        # every section checked now (a renamed method fails here, not on entry); the first names the root
        self.root = [self._resolve(*section) for section in self.sections][0][2]

    @staticmethod
    def _resolve(module_name: str, class_name: str | None, method: str) -> tuple[list[object], str, str]:
        """(owners, attribute, label): a method's class, or for a module-level function every loaded module that
        holds the same function under that name (``from module import function`` copies the reference)."""
        module = importlib.import_module(module_name)
        owner = module if class_name is None else getattr(module, class_name, None)
        if owner is None or not callable(getattr(owner, method, None)):
            where = module_name if class_name is None else f"{module_name}.{class_name}"
            raise ValueError(
                f"SectionTimer: {where} has no callable {method!r} (renamed? update the sections list)"
            )
        if class_name is not None:
            return [owner], method, f"{class_name}.{method}"
        function = getattr(module, method)
        owners = [m for m in list(sys.modules.values()) if getattr(m, method, None) is function]
        return owners, method, method

    def _timed(self, function, label: str | None):
        seconds, own, calls, open_children = self.seconds, self.own_seconds, self.calls, self._open_children

        @functools.wraps(function)
        def wrapper(*args, **kwargs):
            open_children.append(0.0)  # the time of the sections this call opens
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                elapsed = time.perf_counter() - start
                children = open_children.pop()
                if open_children:
                    open_children[-1] += elapsed
                name = label if label is not None else _launch_label(args, kwargs)
                seconds[name] += elapsed
                own[name] += elapsed - children
                calls[name] += 1

        return wrapper

    def _install(self, owners: list[object], attribute: str, label: str | None) -> None:
        """Wrap ``attribute`` of ``owners`` (a class's plain or static method, or a function and every module that
        holds it) with one timer wrapper."""
        wrapped = self._timed(getattr(owners[0], attribute), label)
        for owner in owners:
            original = getattr(owner, "__dict__", {}).get(attribute)  # None: inherited, restored by deleting
            if isinstance(original, classmethod):
                raise ValueError(f"SectionTimer: {attribute!r} of {owner!r} is a classmethod (not supported)")
            self._installed.append((owner, attribute, original))
            setattr(owner, attribute, staticmethod(wrapped) if isinstance(original, staticmethod) else wrapped)

    def __enter__(self) -> SectionTimer:
        if self._installed:
            raise RuntimeError("SectionTimer is already installed (nested use of one timer)")
        try:
            # resolved again: a module imported since __init__ may hold a timed function too
            for owners, method, label in (self._resolve(*section) for section in self.sections):
                self._install(owners, method, label)
            if self.kernels:
                self._install([wp], "launch", None)
                self._install([wp.Launch], "launch", None)
        except BaseException:
            self._uninstall()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self._uninstall()

    def _uninstall(self) -> None:
        while self._installed:  # in reverse order: an attribute wrapped twice gets its first original back
            owner, attribute, original = self._installed.pop()
            if original is None:
                delattr(owner, attribute)
            else:
                setattr(owner, attribute, original)

    def results(self) -> list[Section]:
        """Every section that was called, by decreasing time; shares of the root's time (0 if never called)."""
        total = self.seconds.get(self.root, 0.0)
        rows = [
            Section(name, s, self.calls[name], s / total if total > 0 else 0.0, self.own_seconds[name])
            for name, s in self.seconds.items()
        ]
        return sorted(rows, key=lambda row: (-row.seconds, row.name))

    def table(self) -> str:
        """The results as a markdown table: ms, share of the root, own ms, calls, ms per call."""
        lines = ["| section | ms | share | own ms | calls | ms per call |", "|---|---|---|---|---|---|"]
        for row in self.results():
            lines.append(
                f"| `{row.name}` | {1e3 * row.seconds:.1f} | {100 * row.share:.1f} % | {1e3 * row.own_seconds:.1f} | "
                f"{row.calls} | {1e3 * row.seconds / row.calls:.3f} |"
            )
        return "\n".join(lines)


def _launch_label(args: tuple, kwargs: dict) -> str:
    """``launch:<kernel key>`` of a ``warp.launch(kernel, ...)`` call or of a recorded launch's ``launch()``."""
    first = args[0] if args else kwargs.get("kernel")
    kernel = getattr(first, "kernel", first)  # a wp.Launch holds its kernel
    return f"launch:{getattr(kernel, 'key', type(kernel).__name__)}"


__all__ = ["DEFAULT_SECTIONS", "Section", "SectionTimer"]
