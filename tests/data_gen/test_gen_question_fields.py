"""What questions read from the world state: oriented boxes of the deformed objects, the camera's field of
view, display names unique in the scene and the three-level material taxonomy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from data_gen.assets import material_taxonomy as mt
from data_gen.assets.materials import list_materials
from data_gen.display_names import color_name, display_names
from data_gen.object_boxes import oriented_box
from newtphys.rotations import matrix_to_quat, quat_to_matrix
from newtphys.shards import ShardReader, list_shards


@pytest.mark.parametrize(
    ("rgb", "word"),
    [((0.9, 0.1, 0.1), "red"), ((0.1, 0.3, 0.85), "blue"), ((0.15, 0.7, 0.2), "green"), ((0.95, 0.85, 0.1), "yellow"),
     ((0.95, 0.95, 0.95), "white"), ((0.05, 0.05, 0.05), "black"), ((0.5, 0.5, 0.52), "grey"),
     ((0.45, 0.25, 0.1), "brown"), ((0.95, 0.5, 0.05), "orange")],
)  # fmt: skip
def test_color_words(rgb, word) -> None:
    assert color_name(rgb) == word


def test_display_names_tell_same_kind_objects_apart() -> None:
    red, blue = (0.9, 0.1, 0.1), (0.1, 0.3, 0.85)
    assert display_names(["tennis_ball", "mug"], [red, blue], [0.1, 0.1]) == ["tennis ball", "mug"]
    assert display_names(["ball", "ball", "mug"], [red, blue, red], [0.1, 0.1, 0.2]) == ["red ball", "blue ball", "mug"]
    assert display_names(["ball", "ball"], [red, red], [0.1, 0.2]) == ["small ball", "large ball"]
    assert display_names(["ball", "ball"], [red, red], [0.1, 0.11]) == [None, None]  # nothing tells them apart
    assert display_names(["ball", "ball", "ball"], [red, red, blue], [0.1, 0.3, 0.2]) == [None, None, None]


def test_material_taxonomy_levels() -> None:
    assert mt.classify("metal", 2.0e11, 7850.0) == mt.MaterialTaxonomy("metal", "metal", "steel")
    assert mt.classify("metal", 7.0e10, 2750.0).level_3 == "aluminium"
    assert mt.classify("gel", 1.4e4, 1050.0).level_3 == "gelatin"
    assert len(mt.level_names(1)) == 4 and mt.level_names(2) == list_materials()
    assert set(mt.GROUPS) == set(mt.SPECIFIC) == set(list_materials())
    names3 = mt.level_names(3)
    assert len(names3) == len(set(names3)) >= 24  # specific names never repeat across classes


def test_oriented_box_of_a_rotated_box() -> None:
    q = matrix_to_quat(quat_to_matrix(np.array([np.cos(0.4), 0.3, -0.5, 0.6])))
    q = q / np.linalg.norm(q)
    corners = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.05, 0.05) for z in (-0.02, 0.02)])
    world = corners @ quat_to_matrix(q).T + np.array([1.0, 2.0, 0.5])
    box = oriented_box(world, q)
    assert box["extents"] == pytest.approx([0.2, 0.1, 0.04], abs=1e-12)
    assert box["center"] == pytest.approx([1.0, 2.0, 0.5], abs=1e-12)


def test_generated_world_states_carry_the_question_fields(generated_root: Path) -> None:
    checked = 0
    for split in ("train", "test_ood_gravity"):
        for shard in list_shards(generated_root / split):
            with ShardReader(shard) as r:
                for sid in r.sequences():
                    ws = r.world_state(sid)
                    K = r.intrinsics(sid)
                    h, w = ws.image_size
                    fov_x = np.degrees(2 * np.arctan(0.5 * w / K[0, 0]))
                    names = [o.extra["display_name"] for o in ws.objects]
                    named = [n for n in names if n is not None]
                    assert len(named) == len(set(named)), names
                    for o in ws.objects:
                        tax = o.extra["material_taxonomy"]
                        assert tax["level_2"] == o.material and tax["level_1"] == mt.GROUPS[o.material]
                    for fr in ws.frames:
                        assert fr.camera.extra["fov_x_deg"] == pytest.approx(fov_x, abs=1e-3)
                        for ofs in fr.objects:
                            obj = ws.object_by_id(ofs.id)
                            box = ofs.extra["box"]
                            # the box of the deformed surface: near the rest extents, centred near the COM
                            assert np.allclose(sorted(box["extents"]), sorted(obj.size), rtol=0.1, atol=0.01)
                            assert np.linalg.norm(np.subtract(box["center"], ofs.position)) < 0.5 * max(obj.size)
                            checked += 1
    assert checked > 0
