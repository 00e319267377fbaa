"""The suite's own layout: pytest's default import mode imports test modules by basename (the
test folders are not packages), so two test files of one name stop the whole collection."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

TESTS = Path(__file__).resolve().parents[2]


def test_no_two_test_files_share_a_name() -> None:
    names = Counter(path.name for path in TESTS.rglob("test_*.py"))
    assert len(names) > 100  # the suite itself, not an empty folder
    assert not [name for name, count in names.items() if count > 1]
