"""The VLM report on three hand-made runs of a hand-made set: per-category numbers with baselines, the
heatmap, size bins from the manifest and from a CSV, Young's-modulus and object-count bins, ROI-masked /
counterfactual / cue deltas on matched pairs, "not enough items" for an absent variant, a Pearson r of 1 on
a linear benchmark, and figures drawn without pyplot."""

from __future__ import annotations

import csv
import json
import re
import os
import subprocess
import sys
from pathlib import Path

import pytest

from newtphys import vqa_schema as vs
from probes.vlm.report import build_tables
from probes.vlm.report.loading import load_runs, read_model_csv
from probes.vlm_report import main
from tests.fixtures.vlm_runs import item, write_run, write_set

REPO = Path(__file__).resolve().parents[2]
MASS, SPEED = "F_MASS_OBJECT", "F_KINEMATICS_SPEED_OBJECT"


def _wrong(letter: str) -> str:
    return vs.LETTERS[(vs.LETTERS.index(letter) + 1) % 4]


@pytest.fixture()
def runs_dir(tmp_path: Path) -> Path:
    items, answers = [], {}
    for j in range(8):
        meta = {"num_objects": 2 if j % 2 == 0 else 3}
        ans = "ABCD"[j % 4]
        rows = [
            item(f"m{j}/single", f"s{j}", MASS, meta={**meta, "young_modulus_pa": 1e6 if j < 4 else 1e11}),
            item(f"k{j}/single", f"s{j}", SPEED, meta=meta),
            item(
                f"m{j}/roi_masked/single",
                f"s{j}",
                MASS,
                variant="roi_masked",
                pair=f"m{j}/roi_masked",
                meta=meta,
            ),
        ]
        if j < 2:
            rows.append(
                item(
                    f"k{j}/cf_gravity/single",
                    f"s{j}",
                    "CF_" + SPEED,
                    variant="cf_gravity",
                    pair=f"k{j}/cf_gravity",
                    meta=meta,
                )
            )
        if j < 4:
            rows.append(
                item(
                    f"k{j}/cue_mass_exact/single",
                    f"s{j}",
                    SPEED,
                    variant="cue_mass_exact",
                    pair=f"k{j}/cue_mass_exact",
                    meta=meta,
                )
            )
        for it in rows:
            items.append(it)
            answers[it.idx] = ans
    set_dir = write_set(tmp_path / "vqa" / "test", items, answers)
    for k in range(
        3
    ):  # model k is right on m_j for j < 2(k+1); always right on base k and cues; never on cf/masked
        preds = {}
        for it in items:
            j = int(it.pair.split("/")[0][1:])
            right = {
                "base": it.pair.startswith("k") or j < 2 * (k + 1),
                "roi_masked": False,
                "cf_gravity": False,
                "cue_mass_exact": True,
            }[it.variant]
            preds[(it.idx, 0)] = answers[it.idx] if right else _wrong(answers[it.idx])
        model = {"id": f"org/M{k}", "weights": "pretrained", **({"params_b": 0.5} if k == 0 else {})}
        write_run(tmp_path / "runs" / f"M{k}", set_dir, preds, answerer=f"M{k}", model=model)
    (tmp_path / "sizes.csv").write_text("model,params_b\nM1,7\n")
    (tmp_path / "bench.csv").write_text("model,commonsense,other\nM0,10,\nM1,20,3\norg/M2,30,1\n")
    return tmp_path


def _rows(out: Path, name: str) -> list[dict[str, str]]:
    with open(out / f"{name}.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_report_tables_by_hand(runs_dir: Path) -> None:
    runs = load_runs([runs_dir / "runs"], n_boot=100, sizes_csv=runs_dir / "sizes.csv")
    assert [r.label for r in runs] == ["M0", "M1", "M2"] and [r.params_b for r in runs] == [0.5, 7.0, None]
    tables = {t.name: t for t in build_tables(runs, read_model_csv(runs_dir / "bench.csv"), n_boot=100)}
    pc = {(r[0], r[1]): r for r in tables["per_category"].rows}
    assert pc[("M1", "material_understanding")][3] == 0.5 and pc[("M1", "mechanics")][3] == 1.0
    assert pc[("M1", "overall")][3] == 0.75 and pc[("M1", "overall")][2] == 16  # 8 mass + 8 speed base items
    assert pc[("M0", "material_understanding")][7] == 0.25  # chance beside it
    assert (
        pc[("M0", "material_understanding")][8] == 0.25
    )  # best constant letter of the category: 2 of 8 each
    heat = {r[0]: r for r in tables["subcategory_heatmap"].rows}
    assert tables["subcategory_heatmap"].columns == ["model", "kinematics", "mass", "overall"]
    assert heat["M2"][1:] == [1.0, 0.75, 0.875]
    rank = {r[0]: r for r in build_tables(runs, None, n_boot=0, rank_bin=2)[2].rows}
    # ranked M2 (.875), M1 (.75) | M0 (.625); columns: bin, n, overall, material_understanding, mechanics, models
    assert rank["1-2"][1:5] == [2, 0.8125, 0.625, 1.0] and rank["3-3"][1:6] == [1, 0.625, 0.25, 1.0, "M0"]
    size = tables["by_model_size"]
    assert [r[:3] for r in size.rows] == [["[0, 1)", 1, 0.625], ["[3, 8)", 1, 0.75]] and "M2" in size.note
    ym = {(r[0], r[1]): r for r in tables["by_young_modulus"].rows}
    assert ym[("M1", "[1e6, 1e7) Pa")][2:5] == [4, 4, 1.0] and ym[("M1", "[1e11, 1e13) Pa")][4] == 0.0
    assert ym[("M0", "[1e6, 1e7) Pa")][4] == 0.5
    objs = {(r[0], r[1]): r for r in tables["by_num_objects"].rows}
    assert (
        objs[("M1", "2")][2] == 8
        and objs[("M1", "2")][4] == 0.75
        and objs[("M0", "3")][4] == pytest.approx(5 / 8)
    )
    masked = {(r[0], r[1]): r for r in tables["delta_masked"].rows}
    assert masked[("M0", "roi_masked")][2:7] == [8, 8, 0.25, 0.0, -0.25]
    assert "black_image" in tables["delta_masked"].note and "not enough items" in tables["delta_masked"].note
    cf = {(r[0], r[1]): r for r in tables["delta_counterfactual"].rows}
    assert cf[("M2", "cf_gravity")][2:7] == [2, 2, 1.0, 0.0, -1.0]
    cue = {(r[0], r[1]): r for r in tables["delta_cue"].rows}
    assert cue[("M1", "cue_mass_exact")][2:7] == [4, 4, 1.0, 1.0, 0.0]
    level = tables["delta_level"]
    assert level.empty and "not enough items" in level.note
    corr = {(r[0], r[1]): r for r in tables["correlation"].rows}
    assert corr[("commonsense", "material_understanding")][2] == 3
    assert corr[("commonsense", "material_understanding")][3] == pytest.approx(
        1.0
    )  # 0.25, 0.5, 0.75 vs 10, 20, 30
    assert corr[("commonsense", "mechanics")][3] is None  # constant accuracy: r undefined, not invented
    assert corr[("other", "overall")][2] == 2 and corr[("other", "overall")][5] == "not enough models"


def test_cli_writes_markdown_csv_png_without_pyplot(runs_dir: Path) -> None:
    out = runs_dir / "report"
    # the raw rcParams value: reading rcParams['backend'] would itself resolve the backend through pyplot
    code = (
        "import sys, matplotlib; raw = lambda: dict.__getitem__(matplotlib.rcParams, 'backend'); before = raw();"
        "from probes.vlm_report import main; rc = main(sys.argv[1:]);"
        "print('PYPLOT', 'matplotlib.pyplot' in sys.modules, raw() == before); sys.exit(rc)"
    )
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            code,
            str(runs_dir / "runs"),
            "--out",
            str(out),
            "--n-boot",
            "50",
            "--sizes",
            str(runs_dir / "sizes.csv"),
            "--benchmarks",
            str(runs_dir / "bench.csv"),
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "PYPLOT False True" in proc.stdout
    md = (out / "report.md").read_text()
    assert "| M1 | 16 | 16/16 | 0.750 |" in md and "not enough items" in md
    # every run here covers fewer than 10 sequences: the report says its intervals are not to be relied on
    warning = re.search(r"\*\*Warning:\*\* some runs cover only ([0-9, ]+) sequence\(s\)", md)
    assert warning and all(0 < int(v) < 10 for v in warning.group(1).split(", "))
    for name in (
        "per_category",
        "by_model_rank",
        "subcategory_heatmap",
        "by_model_size",
        "by_young_modulus",
        "by_num_objects",
        "delta_masked",
        "delta_counterfactual",
        "delta_cue",
        "correlation_commonsense",
        "correlation_other",
    ):
        png = out / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    assert not (out / "delta_level.png").exists() and _rows(out, "delta_level") == []
    assert _rows(out, "per_category")[0]["model"] == "M0"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["M1"]["strict"] == 0.75 and summary["M0"]["baselines"]["chance"] == 0.25


def test_report_source_never_uses_pyplot() -> None:
    for path in [REPO / "probes" / "vlm_report.py", *(REPO / "probes" / "vlm" / "report").glob("*.py")]:
        text = path.read_text()
        assert "pyplot" not in text.replace("no pyplot", "").replace("without pyplot", ""), path
        assert "matplotlib.use(" not in text and "switch_backend" not in text, path


def test_bad_inputs_are_named(runs_dir: Path, tmp_path: Path) -> None:
    (tmp_path / "bad.csv").write_text("model,params_b\nM1,seven\n")
    with pytest.raises(ValueError, match=r"bad.csv:2: column 'params_b' = 'seven' is not a number"):
        read_model_csv(tmp_path / "bad.csv")
    assert main([str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")]) == 2


def test_wandb_offline_logs_the_report(runs_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    out = runs_dir / "wb"
    assert (
        main(
            [
                str(runs_dir / "runs" / "M1"),
                "--out",
                str(out),
                "--n-boot",
                "0",
                "--wandb-project",
                "t",
                "--wandb-mode",
                "offline",
            ]
        )
        == 0
    )
    runs = list((out / "wandb").glob("offline-run-*"))
    assert len(runs) == 1 and list(runs[0].glob("*.wandb"))


def test_a_lone_circular_run_without_meta_says_not_enough(tmp_path: Path) -> None:
    items = [item(f"x{k}/single", f"s{k}", MASS) for k in range(4)]
    set_dir = write_set(tmp_path / "vqa" / "test", items, {it.idx: "B" for it in items})
    # x0 right in all rotations, x1 wrong in rotation 3, x2 and x3 wrong in rotation 0
    preds = {
        (f"x{k}/single", r): ("B" if (k == 0 or (k == 1 and r < 3)) else "C")
        for k in range(4)
        for r in range(4)
    }
    write_run(tmp_path / "runs" / "solo", set_dir, preds, answerer="solo", circular=True)
    [run] = load_runs([tmp_path / "runs"], n_boot=0)
    assert run.scores["strict"]["overall"] == 0.25 and run.scores["rotation0"]["strict"]["overall"] == 0.5
    tables = {t.name: t for t in build_tables([run], None, n_boot=0)}
    pc = {r[1]: r for r in tables["per_category"].rows}
    assert (
        pc["overall"][3] == 0.25 and pc["overall"][7] == 0.25**4 and pc["overall"][8] == 0.0
    )  # circular rule
    for name in ("by_young_modulus", "by_model_rank", "by_model_size", "correlation", "delta_masked"):
        assert tables[name].empty and "not enough" in tables[name].note, name
    objs = tables["by_num_objects"].rows  # meta num_objects = 2 everywhere: one bin, circular correctness
    assert [r[1:5] for r in objs] == [["2", 4, 4, 0.25]]
