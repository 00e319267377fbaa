"""Fixtures of the tests of hercs.apps."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.unit.apps.plot_runs import CURVES, _write_run


@pytest.fixture
def run_dirs(tmp_path: Path) -> list[Path]:
    return [_write_run(tmp_path, m, s, c) for (m, s), c in CURVES.items()]
