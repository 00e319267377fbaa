"""The rule that reopens a blind client session (hercs.rediscovery), on a fake clock."""

from __future__ import annotations

import pytest

from hercs.rediscovery import Rediscovery


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_key_never_answered_never_calls_for_a_reopen() -> None:
    clock = Clock()
    rule = Rediscovery(after_s=20.0, max_after_s=160.0, clock=clock)
    for _ in range(100):
        clock.now += 10.0
        assert not rule.missing("hercs/r/config")  # an actor waiting for its run to start


def test_a_lost_key_reopens_after_the_bound_then_backs_off_until_answered() -> None:
    clock = Clock()
    rule = Rediscovery(after_s=20.0, max_after_s=80.0, clock=clock)
    rule.answered("k")
    reopened_at = []
    for _ in range(400):  # one "no queryable" per second for 400 s
        if rule.missing("k"):
            reopened_at.append(clock.now - 100.0)
        clock.now += 1.0
    # the streak starts at the first miss (t=0): 20 s, then waits of 40, 80, 80, ...
    assert reopened_at == [20.0, 60.0, 140.0, 220.0, 300.0, 380.0]
    rule.answered("k")  # an answer ends the streak and its back-off
    clock.now += 5.0
    assert not rule.missing("k")
    clock.now += 20.0
    assert rule.missing("k")


def test_keys_have_streaks_of_their_own() -> None:
    clock = Clock()
    rule = Rediscovery(after_s=10.0, max_after_s=10.0, clock=clock)
    rule.answered("a")
    rule.answered("b")
    assert not rule.missing("a")
    clock.now += 9.0
    assert not rule.missing("b")  # b's streak starts now
    clock.now += 1.0
    assert rule.missing("a") and not rule.missing("b")
    assert rule.missing_for_s("a") == 0.0 and rule.missing_for_s("b") == 1.0


@pytest.mark.parametrize(("after_s", "max_after_s", "match"),
                         [(0.0, 10.0, "after_s: got 0.0"), (20.0, 10.0, "max_after_s: got 10.0")],
                         ids=["zero", "max-below"])
def test_bad_bounds_are_refused_with_the_value(after_s: float, max_after_s: float,
                                               match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Rediscovery(after_s=after_s, max_after_s=max_after_s)
