"""The mutation catalogue stays runnable: every snippet occurs exactly once in its file, every mutant names
existing test files, and names are unique (``tools/mutate.py`` refuses a stale catalogue; this catches it in
the default run instead of at the next ``make mutate``)."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from mutants import MUTANTS  # noqa: E402


def test_every_snippet_occurs_exactly_once_and_changes_the_code():
    stale = []
    for m in MUTANTS:
        count = (ROOT / m.file).read_text().count(m.original)
        if count != 1:
            stale.append(f"{m.name}: {m.file} holds the snippet {count} times")
        assert m.original != m.replacement, m.name
    assert not stale, "update tools/mutants.py: " + "; ".join(stale)


def test_mutants_name_existing_tests_and_are_unique():
    names = [m.name for m in MUTANTS]
    assert len(names) == len(set(names))
    for m in MUTANTS:
        for test in m.selected_tests:
            assert (ROOT / test.split("::")[0]).is_file(), f"{m.name}: no test file {test}"
