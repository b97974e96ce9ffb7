"""Results table from hand-made metrics.json files: grouping, averaging, grading, outputs."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from probes.report import build_rows, column_grades, load_runs, main, make_report, to_markdown


def _write(root: Path, name: str, **data) -> None:
    d = root / name
    d.mkdir(parents=True)
    base = {"status": "finished", "decoder": "LinearHead", "backbone_pretrained": True, "seed": 0}
    (d / "metrics.json").write_text(json.dumps({**base, **data}))


@pytest.fixture()
def runs_dir(tmp_path: Path) -> Path:
    root = tmp_path / "multiruns"
    _write(
        root,
        "0",
        backbone="dinov2",
        supervision="self-supervised",
        task="collision",
        test={"collision_f1": 0.6},
        test_ood_gravity={"collision_f1": 0.5},
    )
    _write(
        root,
        "1",
        backbone="dinov2",
        supervision="self-supervised",
        task="collision",
        seed=1,
        test={"collision_f1": 0.8},
        test_ood_gravity={"collision_f1": 0.7},
    )
    _write(
        root,
        "2",
        backbone="dinov2",
        supervision="self-supervised",
        task="gravity",
        test={"gravity_angular_error_deg": 10.0, "gravity_magnitude_error_n": 2.0},
        test_ood_gravity={"gravity_angular_error_deg": 20.0, "gravity_magnitude_error_n": 8.0},
    )
    _write(
        root,
        "3",
        backbone="clip",
        supervision="language-supervised",
        task="collision",
        test={"collision_f1": 0.4},
        test_ood_gravity={"collision_f1": 0.3},
    )
    _write(
        root,
        "4",
        backbone="clip",
        supervision="language-supervised",
        task="scene_flow",
        test={"scene_flow_epe_m": 0.0123},
        test_ood_gravity={"scene_flow_epe_m": 0.02},
    )
    _write(
        root,
        "5",
        backbone="vit_tiny",
        supervision="supervised",
        task="collision",
        backbone_pretrained=False,
        test={"collision_f1": 0.1},
        test_ood_gravity={"collision_f1": 0.1},
        baselines={
            "test": {"all_positive": {"collision_f1": 0.25}, "all_negative": {"collision_f1": 0.0}},
            "test_ood_gravity": {"all_positive": {"collision_f1": 0.3}},
        },
        skill={"test": {"collision_f1": (0.1 - 0.25) / (1 - 0.25), "mean": (0.1 - 0.25) / (1 - 0.25)}},
    )
    _write(
        root,
        "7",
        backbone="vit_tiny",
        supervision="supervised",
        task="gravity",
        backbone_pretrained=False,
        test={"gravity_angular_error_deg": 16.3, "gravity_magnitude_error_n": 3.8},
        baselines={"test": {"constant": {"gravity_angular_error_deg": 7.5, "gravity_magnitude_error_n": 4.8}}},
        skill={"test": {"gravity_angular_error_deg": 1 - 16.3 / 7.5, "gravity_magnitude_error_n": 1 - 3.8 / 4.8}},
    )
    _write(
        root,
        "6",
        backbone="dino",
        supervision="self-supervised",
        task="collision",
        status="failed",
        test={"collision_f1": 1.0},
    )
    return root


def test_rows_grouped_by_supervision_and_averaged(runs_dir: Path):
    runs = load_runs(runs_dir)
    assert len(runs) == 7  # the failed run is skipped
    rows = build_rows(runs)
    assert [(r.supervision, r.backbone) for r in rows] == [
        ("trivial baseline", "collision: everywhere"),
        ("trivial baseline", "collision: none"),
        ("trivial baseline", "gravity: mean direction, median magnitude"),
        ("self-supervised", "dinov2"),
        ("language-supervised", "clip"),
        ("supervised", "vit_tiny (random)"),
    ]
    everywhere, _, constant, dino = rows[:4]
    assert everywhere.values["Collision F1"] == 0.25 and everywhere.skills is None and everywhere.runs == 1
    assert constant.values["Gravity mAE (deg)"] == 7.5 and constant.values["Gravity magE (N)"] == 4.8
    tiny = rows[-1]
    assert tiny.skills["Collision F1"] == pytest.approx(-0.2) and tiny.skills["Gravity magE (N)"] == pytest.approx(
        1 - 3.8 / 4.8
    )
    assert dino.values["Collision F1"] == pytest.approx(0.7)  # mean of seeds 0.6 and 0.8
    assert dino.values["Gravity-OOD mAE (deg)"] == pytest.approx(20.0)
    assert dino.values["Gravity-OOD magE (N)"] == pytest.approx(8.0)
    assert dino.values["Scene Flow AEE (m)"] is None and dino.runs == 3
    assert rows[4].values["Scene Flow AEE (m)"] == pytest.approx(0.0123)


def test_grades_follow_metric_direction(runs_dir: Path):
    rows = [r for r in build_rows(load_runs(runs_dir)) if not r.is_baseline]
    g = column_grades(rows)["Collision F1"]
    # F1 0.7, 0.4, 0.1: higher is better -> grades 1, 0.5, 0
    assert g == pytest.approx([1.0, 0.5, 0.0])
    # mAE 10 (dinov2), 16.3 (vit_tiny): lower is better
    assert column_grades(rows)["Gravity mAE (deg)"] == [1.0, None, 0.0]


def test_outputs_markdown_csv_png(runs_dir: Path, tmp_path: Path, capsys):
    assert main([str(runs_dir), "--out", str(tmp_path / "report")]) == 0
    md = (tmp_path / "report" / "results.md").read_text()
    assert "| self-supervised | dinov2 | LinearHead | 0.700 | 10.00 | 2.000 | 20.00 | 8.000 | - | 3 |" in md
    assert "0.0123" in md and "vit_tiny (random)" in md
    # baselines are rows; a probe cell carries its skill and is marked when it does not beat the best baseline
    assert "| trivial baseline | collision: everywhere | - | 0.250 | - | - | - | - | - | 1 |" in md
    assert "| supervised | vit_tiny (random) | LinearHead | 0.100 (-0.20) ✗ | 16.30 (-1.17) ✗ | 3.800 (+0.21) |" in md
    with open(tmp_path / "report" / "results.csv") as f:
        table = list(csv.reader(f))
    assert table[0][:4] == ["supervision", "backbone", "decoder", "Collision F1"]
    assert table[0][9] == "Collision F1 skill"
    dino = next(row for row in table if row[1] == "dinov2")
    assert float(dino[3]) == pytest.approx(0.7) and dino[9] == ""
    png = (tmp_path / "report" / "results.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000
    assert "dinov2" in capsys.readouterr().out
    assert to_markdown([]).startswith("| Supervision")


def test_backbone_tapped_at_other_layers_gets_its_own_row(tmp_path: Path):
    _write(
        tmp_path,
        "a",
        backbone="vit_tiny",
        supervision="supervised",
        task="collision",
        backbone_layers=[3],
        test={"collision_f1": 0.2},
    )
    _write(
        tmp_path,
        "b",
        backbone="vit_tiny",
        supervision="supervised",
        task="collision",
        backbone_layers=[1, 3],
        test={"collision_f1": 0.4},
    )
    rows = build_rows(load_runs(tmp_path))
    assert {r.backbone: r.values["Collision F1"] for r in rows} == {
        "vit_tiny [1,3]": 0.4,
        "vit_tiny [3]": 0.2,
    }


def test_empty_or_missing_runs_dir_errors(tmp_path: Path):
    with pytest.raises(FileNotFoundError, match="no finished runs"):
        make_report(tmp_path)
    assert main([str(tmp_path / "nope")]) == 2
