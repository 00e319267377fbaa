"""bench/perf/core_sharing.py quick mode: every phase's loads measured, alone rows at a share of
1, every rate finite and positive (no timing is asserted: the machine is shared)."""

from __future__ import annotations

import math
from pathlib import Path

from tests.support import quick_report


def test_quick_mode_measures_every_load_alone_and_side_by_side(tmp_path: Path) -> None:
    summary, report = quick_report("bench.perf.core_sharing", "core_sharing", tmp_path)
    rates, share = summary["rates_per_cpu_s"], summary["share_of_alone"]
    assert sorted(rates) == ["env alone", "env beside env", "env beside update", "update alone",
                             "update beside env", "update beside update"]
    assert all(math.isfinite(v) and v > 0 for v in rates.values())
    assert share["update alone"] == share["env alone"] == 1.0
    for label, values in summary["samples"].items():  # a load beside itself: two per round
        kind, _, other = label.partition(" beside ")
        assert len(values) == summary["rounds"] * (2 if kind == other else 1), label
    assert "| update | env |" in report
