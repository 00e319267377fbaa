"""The rules that reopen a blind or cut-off client session (hercs.net.rediscovery), on a fake
clock."""

from __future__ import annotations

import pytest

from hercs.net.rediscovery import CutOff, Rediscovery
from tests.support import Clock


def test_a_key_never_answered_never_calls_for_a_reopen() -> None:
    clock = Clock()
    rule = Rediscovery(after_s=20.0, max_after_s=160.0, jitter=0.0, clock=clock)
    for _ in range(100):
        clock.now += 10.0
        assert not rule.missing("hercs/r/config")  # an actor waiting for its run to start


def test_a_lost_key_reopens_after_the_bound_then_backs_off_until_answered() -> None:
    clock = Clock()
    rule = Rediscovery(after_s=20.0, max_after_s=80.0, jitter=0.0, clock=clock)
    rule.answered("k")
    reopened_at = []
    for _ in range(400):  # one "no queryable" per second for 400 s
        if rule.missing("k"):
            reopened_at.append(clock.now - 100.0)
        clock.now += 1.0
    # the streak starts at the first miss (t=0): 20 s, then waits of 40, 80, 80, ...
    assert reopened_at == [20.0, 60.0, 140.0, 220.0, 300.0, 380.0]
    assert rule.streak_s == 80.0
    rule.answered("k")  # an answer ends the streak and its back-off
    clock.now += 5.0
    assert not rule.missing("k")
    for _ in range(19):
        clock.now += 1.0
        assert not rule.missing("k")
    clock.now += 1.0
    assert rule.missing("k")


def test_a_reopen_restarts_every_streak() -> None:
    """Other keys' streaks do not fire right after a reopen: the new session gets the full
    bound for each."""
    clock = Clock()
    rule = Rediscovery(after_s=10.0, max_after_s=10.0, jitter=0.0, clock=clock)
    rule.answered("a")
    rule.answered("b")
    for _ in range(10):
        assert not rule.missing("a") and not rule.missing("b")
        clock.now += 1.0
    assert rule.missing("a")  # both streaks are 10 s old; a's reopen restarts b's
    assert not rule.missing("b")
    clock.now += 11.0
    assert not rule.missing("b")  # 11 s without a miss: b's streak ended, a new one starts


def test_a_rare_miss_long_after_the_last_starts_a_new_streak() -> None:
    clock = Clock()
    rule = Rediscovery(after_s=20.0, max_after_s=160.0, jitter=0.0, clock=clock)
    rule.answered("clusterer_state")
    assert not rule.missing("clusterer_state")
    clock.now += 3600.0
    assert not rule.missing("clusterer_state"), "one miss an hour later is no 20 s streak"


def test_requests_that_each_wait_longer_than_the_bound_still_make_one_streak() -> None:
    clock = Clock()
    rule = Rediscovery(after_s=20.0, max_after_s=160.0, jitter=0.0, clock=clock)
    rule.answered("sample")
    fired = []
    for _ in range(3):  # each request waits 30 s for a queryable, then is sent again at once
        asked = clock.now
        clock.now += 30.0
        fired.append(rule.missing("sample", asked_at=asked))
    # the streak starts when the first request was sent: 30 s ≥ 20; then 40 s are due
    assert fired == [True, False, True]


def test_the_bound_is_stretched_by_the_jitter_only() -> None:
    import random

    waits = []
    for seed in range(20):
        clock = Clock()
        rule = Rediscovery(after_s=20.0, max_after_s=160.0, jitter=0.25,
                           rng=random.Random(seed), clock=clock)
        rule.answered("k")
        rule.missing("k")
        while not rule.missing("k"):
            clock.now += 0.5
        waits.append(clock.now - 100.0)
    assert min(waits) >= 20.0 and max(waits) <= 25.5 and len(set(waits)) > 3


@pytest.mark.parametrize(("after_s", "max_after_s", "match"),
                         [(0.0, 10.0, "after_s: got 0.0"), (20.0, 10.0, "max_after_s: got 10.0")],
                         ids=["zero", "max-below"])
def test_bad_bounds_are_refused_with_the_value(after_s: float, max_after_s: float,
                                               match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Rediscovery(after_s=after_s, max_after_s=max_after_s)


def test_a_session_without_a_router_reopens_after_the_bound_from_the_first_request_sent() -> None:
    """Inserts that each wait 10 s for a queryable during a cut: the streak counts from the send
    of the first one that ended without a router, and fires once the bound is reached."""
    clock = Clock()
    rule = CutOff(after_s=15.0, clock=clock)
    fired = []
    for _ in range(4):
        asked = clock.now
        clock.now += 10.0  # the request's timeout: no queryable, no router
        fired.append(rule.no_router(asked_at=asked))
        clock.now += 2.0  # the inserter's back-off
    # the streak from t=100: 10 s (no), 22 s (yes; it restarts then, at t=122), 12 s, 24 s
    assert fired == [False, True, False, True]
    assert rule.streak_s == 24.0


def test_a_router_seen_or_an_answer_ends_the_streak() -> None:
    """A cut shorter than the bound plus Zenoh's reconnect never calls for a reopen: the
    session's own reconnect brings its router back first."""
    clock = Clock()
    rule = CutOff(after_s=15.0, clock=clock)
    for _ in range(3):  # a streak of 14 s each time, ended by the router seen again
        for _ in range(15):
            assert not rule.no_router()
            clock.now += 1.0
        rule.connected()
    assert not rule.no_router()


def test_concurrent_requests_count_from_the_earliest_send() -> None:
    clock = Clock()
    rule = CutOff(after_s=15.0, clock=clock)
    clock.now += 10.0
    assert not rule.no_router(asked_at=clock.now - 1.0)  # a short request: since t=109
    assert rule.no_router(asked_at=clock.now - 15.0)  # a long one sent at t=95: 15 s now


@pytest.mark.parametrize("after_s", [0.0, -1.0], ids=["zero", "negative"])
def test_a_bound_that_is_not_positive_is_refused(after_s: float) -> None:
    with pytest.raises(ValueError, match=f"after_s: got {after_s}"):
        CutOff(after_s=after_s)
