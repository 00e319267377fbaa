"""Failed-goal buffer: refit every `capacity` new failed goals (first when it fills), ring
overwrite keeps the newest, and the state round trip."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.clusterer.failed_goals import FailedGoalBuffer


def _goal(i: int) -> np.ndarray:
    return np.array([i, -i, 0.5 * i], np.float32)


@pytest.mark.parametrize("capacity", [150, 7], ids=["paper-150", "small-7"])
def test_refit_due_exactly_once_per_capacity_new_goals(capacity: int) -> None:
    fgb = FailedGoalBuffer(capacity)
    due_at = []
    for i in range(1, 4 * capacity + 1):
        fgb.add(_goal(i))
        if fgb.refit_due:
            due_at.append(i)
            fgb.mark_fitted()
    assert due_at == [capacity, 2 * capacity, 3 * capacity, 4 * capacity]


def test_refit_stays_due_until_marked_and_count_restarts_at_the_fit() -> None:
    fgb = FailedGoalBuffer(10)
    for i in range(12):  # fit late, after 12
        fgb.add(_goal(i))
    assert fgb.refit_due
    fgb.mark_fitted()
    for i in range(9):
        fgb.add(_goal(i))
        assert not fgb.refit_due
    fgb.add(_goal(9))
    assert fgb.refit_due


def test_ring_overwrite_keeps_last_capacity_oldest_first() -> None:
    fgb = FailedGoalBuffer(150)
    for i in range(200):
        fgb.add(_goal(i))
    assert len(fgb) == 150 and fgb.total_added == 200
    np.testing.assert_array_equal(fgb.goals(), np.stack([_goal(i) for i in range(50, 200)]))


def test_partial_buffer_returns_what_it_holds() -> None:
    fgb = FailedGoalBuffer(5)
    for i in range(3):
        fgb.add(_goal(i))
    assert len(fgb) == 3 and not fgb.refit_due
    np.testing.assert_array_equal(fgb.goals(), np.stack([_goal(i) for i in range(3)]))


def test_rejects_bad_goals() -> None:
    fgb = FailedGoalBuffer(4)
    with pytest.raises(ValueError, match="finite"):
        fgb.add(np.array([0.0, np.nan, 1.0]))
    with pytest.raises(ValueError, match="finite"):
        fgb.add(np.zeros(2))
