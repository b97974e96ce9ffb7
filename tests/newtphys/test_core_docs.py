"""The data contract a user reads (docs/data_contract.md) says what schema.py says, and the repository's
documents point nowhere outside the repository."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from newtphys import schema

REPO = Path(__file__).resolve().parents[2]
CONTRACT = REPO / "docs" / "data_contract.md"


def _contract_rows() -> dict[str, tuple[str, str, str]]:
    rows = {}
    for line in CONTRACT.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 5 and cells[0].startswith("`"):
            rows[cells[0].strip("`")] = (cells[1], cells[2], cells[3])
    return rows


def _shape_text(shape: tuple) -> str:
    return ",".join(str(s) for s in shape)


@pytest.mark.parametrize("name", [*schema.MAP_NAMES, *schema.CAMERA_ARRAYS])
def test_contract_document_lists_every_array_as_schema_declares_it(name: str) -> None:
    spec = schema.MAPS[name] if name in schema.MAPS else schema.CAMERA_ARRAYS[name]
    rows = _contract_rows()
    assert name in rows, f"{name} missing from {CONTRACT}"
    shape, dtype, unit = rows[name]
    assert shape == _shape_text(spec.shape)
    assert np.dtype(dtype) == spec.dtype
    assert unit == spec.unit


def test_contract_document_lists_nothing_schema_lacks() -> None:
    extra = set(_contract_rows()) - set(schema.MAP_NAMES) - set(schema.CAMERA_ARRAYS) - {schema.WORLD_STATE}
    assert extra == set()
    assert f"schema version {schema.SCHEMA_VERSION}" in CONTRACT.read_text().splitlines()[0]


def test_documents_point_nowhere_outside_the_repository() -> None:
    documents = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
    for doc in documents:
        text = doc.read_text()
        assert "shared/" not in text and "../" not in text, doc
        for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):  # relative links resolve inside the repo
            if "://" not in target:
                assert (doc.parent / target).resolve().exists(), (doc, target)
