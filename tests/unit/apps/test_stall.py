"""The stall bound of `hercs up` (hercs/apps/launch/stall.py): the run's own pace times
`launch.stall_factor`, from the config's first epoch until an epoch has been timed."""

from __future__ import annotations

import pytest

from hercs.apps.launch.stall import STARTUP_S, StallWatch, expected_first_epoch_s
from hercs.config import HercsConfig, apply_overrides
from hercs.config.limits import MAX_STALL_S
from tests.support import Clock


def test_before_the_first_epoch_the_bound_is_the_factor_times_the_configs_first_epoch(
        ) -> None:
    clock = Clock()
    watch = StallWatch(factor=3, first_epoch_s=100.0, clock=clock)
    clock.now += 1000
    assert not watch.stalled(), "the clock has not begun: remote actors may join later"
    watch.begin()
    clock.now += 299
    assert not watch.stalled()
    clock.now += 1
    assert watch.stalled() and watch.bound_s == 300
    assert watch.describe() == (
        "no epoch has ended for 300 s (since the run began); the bound is "
        "launch.stall_factor 3 x the first epoch this config should take at most, 100 s; "
        "no episode has been stored since the run began")


def test_the_bound_follows_the_slowest_epoch_so_far() -> None:
    clock = Clock()
    watch = StallWatch(factor=3, first_epoch_s=1000.0, clock=clock)
    watch.begin()
    clock.now += 20
    watch.epoch_ended(1)  # the first epoch: the services' start and the epoch
    clock.now += 5
    watch.epoch_ended(2)
    assert watch.bound_s == 60, "the slowest, not the last: a restart costs about a start"
    clock.now += 59
    watch.episode_stored()
    clock.now += 1
    watch.epoch_ended(2)  # a repeated row (a restarted learner) is no progress
    assert watch.stalled()
    assert watch.describe() == (
        "no epoch has ended for 60 s (since epoch 2 ended); the bound is "
        "launch.stall_factor 3 x the slowest epoch so far, 20.0 s; "
        "the last episode was stored 1 s ago")
    watch.epoch_ended(3)
    assert not watch.stalled() and watch.bound_s == 180, "epoch 3 took 60 s, the slowest"


def test_a_run_without_actors_is_held_not_stalled_and_starts_afresh_when_they_return(
        ) -> None:
    """Remote actors gone (their node died): the run waits for them, for as long as it
    takes; back, they get the whole bound again, at the pace timed before."""
    clock = Clock()
    watch = StallWatch(factor=3, first_epoch_s=1000.0, clock=clock)
    watch.begin()
    clock.now += 10
    watch.epoch_ended(1)
    clock.now += 29
    watch.hold()
    clock.now += 10_000
    assert not watch.stalled() and watch.quiet_s() == 0
    watch.begin()
    clock.now += 29
    assert not watch.stalled(), "the bound counts from the actors' return"
    clock.now += 1
    assert watch.stalled() and watch.bound_s == 30


@pytest.mark.parametrize("slowest_s", [None, 3 * 3600.0], ids=["first-epoch", "slowest-epoch"])
def test_the_bound_is_at_most_a_day_whatever_the_pace(slowest_s: float | None) -> None:
    """The first epoch's estimate grows with the config (a batch of 10^9 rows made it 922
    days) and a slow epoch times the factor can be long: the bound stops at MAX_STALL_S."""
    clock = Clock()
    watch = StallWatch(factor=10, first_epoch_s=1e9, clock=clock)
    watch.begin()
    if slowest_s is not None:
        clock.now += slowest_s
        watch.epoch_ended(1)
    assert watch.bound_s == MAX_STALL_S == 24 * 3600
    clock.now += MAX_STALL_S - 1
    assert not watch.stalled()
    clock.now += 1
    assert watch.stalled()
    assert ", capped at 86400 s (a day); " in watch.describe()


def test_factor_0_never_stalls() -> None:
    clock = Clock()
    watch = StallWatch(factor=0, first_epoch_s=1.0, clock=clock)
    watch.begin()
    clock.now += 1e9
    assert not watch.stalled()


@pytest.mark.parametrize(
    ("overrides", "at_least_s", "at_most_s"),
    [([], 90.0, 130.0),
     (["task.name=reach", "training.cycles_per_epoch=3", "ddpg.hidden_size=16"],
      STARTUP_S, STARTUP_S + 5)],
    ids=["paper-push", "tiny-reach"],
)
def test_the_first_epoch_expected_of_a_config(overrides: list[str], at_least_s: float,
                                              at_most_s: float) -> None:
    """The paper's FetchPush epoch took 34-37 s on the development machine (committed runs);
    the estimate, counted as if on one core, is a few times that, and a tiny test run's is the
    services' start."""
    expected = expected_first_epoch_s(apply_overrides(HercsConfig(), overrides))
    assert at_least_s <= expected <= at_most_s
