"""``python -m newtphys {validate,info,view,stats,merge-index,validate-vqa,view-vqa,subset-vqa,export-vqa}``: tools over shards and question sets that
need only the core."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from newtphys import schema
from newtphys.shards import ShardError, ShardReader, list_shards
from newtphys.validate import validate_paths


def _shards_under(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    found = list_shards(path)
    for sub in sorted(p for p in path.iterdir() if p.is_dir()) if path.is_dir() else []:
        found += list_shards(sub)
    return found


def cmd_validate(args: argparse.Namespace) -> int:
    problems = validate_paths(args.paths, deep=args.deep)
    errors = [p for p in problems if p.severity == "error"]
    for p in problems:
        print(p)
    checked = sum(len(_shards_under(Path(p))) for p in args.paths if Path(p).exists())
    print(f"checked {checked} shard(s): {len(errors)} error(s), {len(problems) - len(errors)} warning(s)")
    return 1 if errors else 0


def _human(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024:
            return f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def cmd_info(args: argparse.Namespace) -> int:
    path = Path(args.path)
    shards = _shards_under(path)
    if not shards:
        print(f"error: {path}: no shards found", file=sys.stderr)
        return 1
    header = f"{'shard':<28} {'sequence':<24} {'split':<17} {'frames':>6} {'HxW':>9} {'objects':>7} {'g m/s2':>7} {'size':>10}"
    print(header)
    print("-" * len(header))
    total_seq = total_frames = total_bytes = 0
    maps_seen: set[str] = set()
    for shard in shards:
        size = shard.stat().st_size
        total_bytes += size
        try:
            with ShardReader(shard) as r:
                for i, sid in enumerate(r.sequences()):
                    ws = r.world_state(sid)
                    maps_seen |= {n for n in schema.MAP_NAMES if n in r.file[sid]}
                    h, w = ws.image_size
                    print(f"{(shard.parent.name + '/' + shard.name) if i == 0 else '':<28} {sid:<24} {ws.split:<17} "
                          f"{ws.num_frames:>6} {f'{h}x{w}':>9} {len(ws.objects):>7} {ws.gravity_magnitude:>7.2f} "
                          f"{_human(size) if i == 0 else '':>10}")
                    total_seq += 1
                    total_frames += ws.num_frames
        except ShardError as e:
            print(f"{shard.name:<28} error: {e}")
    print("-" * len(header))
    print(f"{len(shards)} shard(s), {total_seq} sequence(s), {total_frames} frame(s), {_human(total_bytes)} on disk")
    print(f"maps: {', '.join(n for n in schema.MAP_NAMES if n in maps_seen)}")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from newtphys.viz import view_sequence

    path = Path(args.path)
    shards = _shards_under(path)
    shard = None
    for s in shards:
        with ShardReader(s) as r:
            if args.sequence is None or args.sequence in r.sequences():
                shard = s
                break
    if shard is None:
        print(f"error: {path}: no shard holds sequence {args.sequence!r}", file=sys.stderr)
        return 1
    for out in view_sequence(shard, args.sequence, args.out, video=not args.no_video):
        print(f"wrote {out}")
    return 0


def cmd_stats(args: argparse.Namespace) -> int:
    from newtphys.stats import _markdown, write_stats

    out = Path(args.out) if args.out else Path(args.path) / "stats"
    try:
        summary = write_stats(args.path, out)
    except FileNotFoundError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(_markdown(summary))
    print(f"wrote {out / 'stats.png'}, {out / 'summary.md'}, {out / 'summary.json'}")
    if args.vqa:
        from newtphys.vqa_viz import stats_panel

        for set_dir in _question_sets_under(Path(args.vqa)):
            print(f"wrote {stats_panel(set_dir, out / f'vqa-{set_dir.name}.png')}")
    return 0


def _question_sets_under(path: Path) -> list[Path]:
    """``path`` itself when it holds a question set, else every ``<path>/<split>`` that does."""
    from newtphys.vqa_schema import QUESTIONS_FILE

    if (path / QUESTIONS_FILE).is_file() or not path.is_dir():
        return [path]
    return sorted(p for p in path.iterdir() if (p / QUESTIONS_FILE).is_file()) or [path]


def cmd_validate_vqa(args: argparse.Namespace) -> int:
    from newtphys.vqa_validate import validate_question_set

    sets = [s for p in args.paths for s in _question_sets_under(Path(p))]
    problems = [problem for s in sets for problem in validate_question_set(s)]
    errors = [p for p in problems if p.severity == "error"]
    for p in problems:
        print(p)
    print(f"checked {len(sets)} question set(s): {len(errors)} error(s), {len(problems) - len(errors)} warning(s)")
    return 1 if errors else 0


def cmd_view_vqa(args: argparse.Namespace) -> int:
    from newtphys.vqa_viz import contact_sheet

    sets = _question_sets_under(Path(args.path))
    print(f"wrote {contact_sheet(sets[0], args.out, count=args.count, seed=args.seed)}")
    return 0


def cmd_subset_vqa(args: argparse.Namespace) -> int:
    from newtphys.vqa_subset import write_subset

    manifest = write_subset(_question_sets_under(Path(args.path))[0], args.out, args.size, args.seed)
    print(f"wrote {manifest['size']} items to {args.out}: per sub-category {manifest['counts']['sub_category']}")
    return 0


def cmd_export_vqa(args: argparse.Namespace) -> int:
    from newtphys.vqa_export import export

    path = export(_question_sets_under(Path(args.path))[0], args.format, args.out, args.name, args.image_mode,
                  None if args.mode == "all" else args.mode)  # fmt: skip
    print(f"wrote {path}")
    return 0


def cmd_merge_index(args: argparse.Namespace) -> int:
    from newtphys.shards import merge_index

    try:
        report = merge_index(args.split_dir, args.expect)
    except ShardError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"{Path(args.split_dir) / schema.INDEX_FILENAME}: {report.shards} shard(s), {report.sequences} sequence(s), "
          f"{report.frames} frame(s)" + (f"; shards missing (jobs unfinished?): {report.missing_shards}"
                                          if report.missing_shards else ""))
    return 1 if report.missing_shards else 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m newtphys", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    v = sub.add_parser("validate", help="check shards / split directories against the data contract")
    v.add_argument("paths", nargs="+", help="shard files, split directories or dataset roots")
    v.add_argument("--deep", action="store_true",
                   help="also run the cross-map physics checks (flow vs scene flow, gravity vs mass, labels, contacts)")
    v.set_defaults(func=cmd_validate)
    i = sub.add_parser("info", help="summary table of the shards under PATH")
    i.add_argument("path")
    i.set_defaults(func=cmd_info)
    w = sub.add_parser("view", help="contact sheet PNG and video of one sequence")
    w.add_argument("path", help="a shard, split directory or dataset root")
    w.add_argument("--sequence", default=None, help="sequence id (default: the first one found)")
    w.add_argument("--out", required=True, help="output path; .png and .mp4/.gif are written beside it")
    w.add_argument("--no-video", action="store_true")
    w.set_defaults(func=cmd_view)
    st = sub.add_parser("stats", help="dataset statistics plots and summary table (from world states)")
    st.add_argument("path", help="a split directory or dataset root")
    st.add_argument("--out", default=None, help="output directory (default: PATH/stats)")
    st.add_argument("--vqa", default=None, help="also draw the VQA panel of the question sets under this directory")
    st.set_defaults(func=cmd_stats)
    mi = sub.add_parser("merge-index", help="rebuild a split's index.json from the shards many jobs wrote, "
                                            "checking they form one split (disjoint sequences, one config)")
    mi.add_argument("split_dir")
    mi.add_argument("--expect", type=int, default=None, help="number of sequences the split must hold")
    mi.set_defaults(func=cmd_merge_index)
    q = sub.add_parser("validate-vqa", help="check question sets against the VQA contract (docs/vqa_contract.md)")
    q.add_argument("paths", nargs="+", help="a question-set directory (<vqa_dir>/<split>) or a VQA root")
    q.set_defaults(func=cmd_validate_vqa)
    vv = sub.add_parser("view-vqa", help="contact sheet of sample questions (images, question, options, answer)")
    vv.add_argument("path", help="a question-set directory or a VQA root (its first split)")
    vv.add_argument("--out", required=True, help="output PNG")
    vv.add_argument("--count", type=int, default=12)
    vv.add_argument("--seed", type=int, default=0)
    vv.set_defaults(func=cmd_view_vqa)
    sb = sub.add_parser("subset-vqa", help="balanced subset: equal per sub-category, about equal per object count")
    sb.add_argument("path", help="a question-set directory or a VQA root (its first split)")
    sb.add_argument("--out", required=True, help="output question-set directory")
    sb.add_argument("--size", type=int, default=15000)
    sb.add_argument("--seed", type=int, default=42)
    sb.set_defaults(func=cmd_subset_vqa)
    ex = sub.add_parser("export-vqa", help="a question set as a VLMEvalKit TSV or an lmms-eval task directory")
    ex.add_argument("path", help="a question-set directory or a VQA root (its first split)")
    ex.add_argument("--format", required=True, choices=["vlmevalkit", "lmms-eval"])
    ex.add_argument("--out", required=True, help="output directory ($LMUData for VLMEvalKit; the task dir for lmms-eval)")
    ex.add_argument("--name", default=None, help="dataset / task name (default: newtphys_<split>)")
    ex.add_argument("--image-mode", default="base64", choices=["base64", "path"],
                    help="VLMEvalKit: images inline as base64 (default) or as absolute paths (image_path)")
    ex.add_argument("--mode", default="all", choices=["all", "single", "multi"],
                    help="single: only one-image items (for single-image models)")
    ex.set_defaults(func=cmd_export_vqa)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))
