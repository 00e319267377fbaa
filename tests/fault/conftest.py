"""Every fault case, whatever it asserts itself: no metrics row a run wrote under its tmp_path
records a policy lag below zero (issue 57: the lag is never negative, by construction). A run
is a folder with a `logs/` beside its metrics.csv (what `hercs up` makes); copies of committed
runs, some written before the fix (docs/results/lag_audit.md), are not this test's runs."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from hercs.run.rundir import LOGS, METRICS

LAG_COLUMNS = ("policy_lag", "policy_lag_request", "policy_lag_p50", "policy_lag_p95",
               "policy_lag_max")


def negative_lags(root: Path) -> list[str]:
    """`file: epoch N column=value` for every lag cell below zero under `root`."""
    found = []
    for path in sorted(root.rglob(METRICS)):
        if not (path.parent / LOGS).is_dir():
            continue
        try:
            with path.open(newline="") as f:
                rows = list(csv.DictReader(f))
        except (OSError, csv.Error, UnicodeDecodeError):
            continue  # a file a test made unreadable on purpose
        for row in rows:
            for column in LAG_COLUMNS:
                try:
                    value = float(row.get(column) or "nan")
                except ValueError:
                    continue
                if not math.isnan(value) and value < 0:
                    found.append(f"{path}: epoch {row.get('epoch')} {column}={value}")
    return found


@pytest.fixture(autouse=True)
def no_negative_lag(tmp_path: Path) -> Iterator[None]:
    """Checked after the test, before its tmp_path goes (this fixture depends on it)."""
    yield
    found = negative_lags(tmp_path)
    assert not found, "a run recorded a negative policy lag:\n" + "\n".join(found)
