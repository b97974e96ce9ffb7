"""Mutation testing of the label paths: plant each bug of ``tools/mutants.py`` in a copy, run its tests.

    python tools/mutate.py                 # every mutant (what ``make mutate`` runs)
    python tools/mutate.py --list          # the catalogue
    python tools/mutate.py --only stress_sign_flipped --only collision_map_all_false
    python tools/mutate.py --json bench/results/mutate.json

The working tree is never modified: the repository's files (tracked, and untracked ones git does not
ignore) are snapshot when the run starts and copied to a temporary directory once per mutant; the
snippet is replaced there, and the mutant's selected default-run tests (``-m "not slow" -x``) run in
that copy under a per-mutant timeout.
Before the mutants, the union of all selected tests runs once on the unmodified copy (the baseline):
a mutant is only "killed" by a test that passes without it.

A mutant is killed when a test fails (the table names the first one) or the run times out; it
survives when every selected test passes. Exit status: 0 when every mutant not marked equivalent is
killed, 1 when one survives, 2 when the catalogue is stale or the baseline fails.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mutants import MUTANTS, Mutant  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PYTEST_ARGS = ("-m", "not slow", "-x", "-q", "-p", "no:cacheprovider", "--no-header")


@dataclass
class Outcome:
    mutant: str
    file: str
    status: str
    """killed | timeout | SURVIVED | equivalent (a listed equivalent mutant that survived)."""
    killed_by: str
    seconds: float


def repository_files(root: Path) -> list[str]:
    """Tracked files and untracked files git does not ignore (so uncommitted tests count), relative paths."""
    out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                         cwd=root, check=True, capture_output=True).stdout
    return sorted({p for p in out.decode().split("\0") if p and (root / p).is_file()})


def copy_tree(root: Path, files: list[str], dest: Path) -> None:
    for rel in files:
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / rel, target)


def stale_mutants(root: Path, mutants: tuple[Mutant, ...]) -> list[str]:
    """Mutants whose snippet does not occur exactly once in their file (the catalogue needs an update)."""
    problems = []
    for m in mutants:
        path = root / m.file
        count = path.read_text().count(m.original) if path.is_file() else -1
        if count != 1:
            where = "file missing" if count < 0 else f"snippet found {count} times"
            problems.append(f"{m.name}: {m.file}: {where}: {m.original!r}")
    return problems


def apply_mutant(copy_root: Path, mutant: Mutant) -> None:
    path = copy_root / mutant.file
    text = path.read_text()
    path.write_text(text.replace(mutant.original, mutant.replacement, 1))


def first_failure(junit_xml: Path) -> str:
    """Node id of the first failing or erroring test case of a junit report ('' if none)."""
    if not junit_xml.is_file():
        return ""
    for case in ET.parse(junit_xml).getroot().iter("testcase"):
        if case.find("failure") is not None or case.find("error") is not None:
            module = case.get("classname", "").replace(".", "/")
            return f"{module}.py::{case.get('name', '?')}"
    return ""


def run_tests(copy_root: Path, tests: tuple[str, ...], timeout_s: float) -> tuple[str, str, float]:
    """pytest in ``copy_root``: (status 'passed' | 'failed' | 'timeout', first failing test, seconds)."""
    report = copy_root / "mutate-junit.xml"
    env = {**os.environ, "WANDB_MODE": "offline", "HF_HUB_OFFLINE": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    env.pop("PYTHONPATH", None)  # the copy's own code (pytest pythonpath ".") must be what is imported
    cmd = [sys.executable, "-m", "pytest", *PYTEST_ARGS, f"--junitxml={report}", *tests]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, cwd=copy_root, env=env, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return "timeout", f"timeout after {timeout_s:.0f} s", time.perf_counter() - t0
    seconds = time.perf_counter() - t0
    if proc.returncode == 0:
        return "passed", "", seconds
    if proc.returncode == 5:
        raise SystemExit(f"no tests collected for {tests} in {copy_root}: fix the catalogue's test selection")
    last_line = proc.stdout.strip().splitlines()[-1:]
    failed = first_failure(report) or f"pytest exit {proc.returncode}: {last_line}"
    return "failed", failed, seconds


def check_imports_come_from(copy_root: Path) -> None:
    """The copy's packages, not an editable install elsewhere, are imported from it."""
    code = "import data_gen, newtphys, probes; print(data_gen.__file__, newtphys.__file__, probes.__file__)"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([sys.executable, "-c", code], cwd=copy_root, env=env, check=True,
                         capture_output=True, text=True).stdout.split()
    outside = [p for p in out if not Path(p).resolve().is_relative_to(copy_root.resolve())]
    if outside:
        raise SystemExit(f"imports resolve outside the copy {copy_root}: {outside}")


def run_mutant(mutant: Mutant, snapshot: Path, files: list[str], timeout_s: float) -> Outcome:
    with tempfile.TemporaryDirectory(prefix=f"mutant-{mutant.name}-") as tmp:
        copy_root = Path(tmp)
        copy_tree(snapshot, files, copy_root)
        apply_mutant(copy_root, mutant)
        status, detail, seconds = run_tests(copy_root, mutant.selected_tests, timeout_s)
    if status == "passed":
        return Outcome(mutant.name, mutant.file, "equivalent" if mutant.equivalent else "SURVIVED",
                       mutant.equivalent or "", seconds)
    return Outcome(mutant.name, mutant.file, "killed" if status == "failed" else "timeout", detail, seconds)


def table(outcomes: list[Outcome]) -> str:
    rows = [("mutant", "file", "result", "s")]
    for o in outcomes:
        result = {"killed": f"killed by {o.killed_by}", "timeout": o.killed_by,
                  "equivalent": f"equivalent: {o.killed_by}", "SURVIVED": "SURVIVED"}[o.status]
        rows.append((o.mutant, o.file, result, f"{o.seconds:.0f}"))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    lines = [" | ".join(c.ljust(w) for c, w in zip(r, widths)) for r in rows]
    lines.insert(1, "-+-".join("-" * w for w in widths))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", action="append", default=[], help="run only this mutant (repeatable)")
    parser.add_argument("--list", action="store_true", help="print the catalogue and exit")
    parser.add_argument("--timeout", type=float, default=600.0,
                        help="seconds per mutant (and for the baseline)")
    parser.add_argument("--no-baseline", action="store_true",
                        help="skip the unmutated run of the selected tests")
    parser.add_argument("--json", type=Path, help="also write the outcomes to this JSON file")
    args = parser.parse_args(argv)

    unknown = sorted(set(args.only) - {m.name for m in MUTANTS})
    if unknown:
        parser.error(f"unknown mutants {unknown}; see --list")
    mutants = tuple(m for m in MUTANTS if not args.only or m.name in args.only)
    if args.list:
        for m in mutants:
            print(f"{m.name:44s} {m.file:28s} {', '.join(m.selected_tests)}")
        return 0
    with tempfile.TemporaryDirectory(prefix="mutant-snapshot-") as snapshot:
        return run_all(mutants, Path(snapshot), args)


def run_all(mutants: tuple[Mutant, ...], snapshot: Path, args: argparse.Namespace) -> int:
    """Snapshot the working tree (edits made while this runs do not leak in), then baseline and mutants."""
    files = repository_files(REPO)
    copy_tree(REPO, files, snapshot)
    stale = stale_mutants(snapshot, mutants)
    if stale:
        print("stale mutant catalogue (tools/mutants.py):\n  " + "\n  ".join(stale), file=sys.stderr)
        return 2
    t_start = time.perf_counter()
    if not args.no_baseline:
        selected = tuple(dict.fromkeys(t for m in mutants for t in m.selected_tests))
        with tempfile.TemporaryDirectory(prefix="mutant-baseline-") as tmp:
            copy_tree(snapshot, files, Path(tmp))
            check_imports_come_from(Path(tmp))
            status, detail, seconds = run_tests(Path(tmp), selected, args.timeout)
        print(f"baseline ({len(selected)} test files, unmutated): {status} in {seconds:.0f} s", flush=True)
        if status != "passed":
            print(f"the selected tests fail without any mutant: {detail}", file=sys.stderr)
            return 2

    outcomes = []
    for i, mutant in enumerate(mutants, 1):
        outcome = run_mutant(mutant, snapshot, files, args.timeout)
        outcomes.append(outcome)
        print(f"[{i}/{len(mutants)}] {outcome.mutant}: {outcome.status} {outcome.killed_by} "
              f"({outcome.seconds:.0f} s)", flush=True)
    wall = time.perf_counter() - t_start

    killed = sum(o.status in ("killed", "timeout") for o in outcomes)
    survivors = [o.mutant for o in outcomes if o.status == "SURVIVED"]
    print()
    print(table(outcomes))
    print(f"\n{killed} killed / {len(outcomes)} total; "
          f"{sum(o.status == 'equivalent' for o in outcomes)} equivalent survived; "
          f"survivors: {', '.join(survivors) or 'none'}; wall time {wall / 60:.1f} min")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"wall_time_s": wall, "killed": killed, "total": len(outcomes),
                                         "outcomes": [asdict(o) for o in outcomes]}, indent=1) + "\n")
    return 1 if survivors else 0


if __name__ == "__main__":
    sys.exit(main())
