"""Where one of ``bench_peers.py``'s scenes spends its simulation time, and a digest of what it recorded.

Runs the scene once untimed (kernel loading, caches), then once under
:class:`data_gen.sim.section_timer.SectionTimer` (wall-clock timers around the simulator's step, broad phase,
solves, records and every warp launch; times are inclusive, shares are of ``Simulator.run``), and prints the
table. The run's :func:`records_digest` (SHA-256 over every recorded array, the energies, the contact events and
the Newton iterations) tells whether a change to the solver kept the results bit for bit: run the old and the new
code and compare the two lines.

    python bench/profile_sim.py --scene stiff_10
    python bench/profile_sim.py --scene soft_5 --no-kernels      # methods only
    python bench/profile_sim.py --scene stiff_10 --json out.json  # the table as JSON too

One thread, set-up (skinning, cubature) outside the timed run, as in ``bench_peers.py``. The timers cost about a
microsecond per call: the table reads a few per cent above an untimed run, printed beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_peers import DURATION_S, FPS, SCENES, newtphys_simulator  # noqa: E402

from data_gen.sim.records_digest import records_digest  # noqa: E402
from data_gen.sim.section_timer import SectionTimer  # noqa: E402


def profile_scene(name: str, kernels: bool = True) -> dict:
    """One untimed and one timed run of scene ``name``: the untimed run's wall time (s), the table's rows and the
    timed run's digest and Newton iterations (the two runs' digests must agree: the timers change nothing)."""
    frames = int(round(DURATION_S * FPS)) + 1
    sim = newtphys_simulator(SCENES[name])
    start = time.perf_counter()
    plain = sim.run(frames, fps=FPS)
    plain_s = time.perf_counter() - start
    with SectionTimer(kernels=kernels) as timer:
        timed = sim.run(frames, fps=FPS)
    digest = records_digest(timed)
    if digest != records_digest(plain):
        raise RuntimeError(f"{name}: the timed run recorded other values than the untimed one (timers must not)")
    return {
        "scene": name,
        "untimed_wall_s": plain_s,
        "newton_iterations": int(timed.info.newton_iterations),
        "digest": digest,
        "sections": [asdict(row) for row in timer.results()],
        "table": timer.table(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="stiff_10", choices=sorted(SCENES))
    parser.add_argument("--no-kernels", action="store_true", help="time the methods only, not each warp launch")
    parser.add_argument("--json", type=Path, default=None, help="also write the result here")
    args = parser.parse_args()
    out = profile_scene(args.scene, kernels=not args.no_kernels)
    print(out["table"])
    print(f"\n{args.scene}: untimed run {out['untimed_wall_s']:.3f} s; "
          f"Newton iterations {out['newton_iterations']}; records digest {out['digest']}")
    if args.json is not None:
        args.json.write_text(json.dumps({k: v for k, v in out.items() if k != "table"}, indent=2))


if __name__ == "__main__":
    main()
