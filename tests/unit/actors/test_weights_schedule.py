"""The actor's weights schedule (hercs.actors.weights_schedule), driven directly: what an
actor waits for before each episode, per training schedule, and how insert outcomes move
lockstep's minimum version. The actor service only carries these waits out."""

from __future__ import annotations

from hercs.actors.weights_schedule import ACT_NOW, Need, Wait, WeightsSchedule


def test_asynchronous_without_a_bound_never_waits() -> None:
    schedule = WeightsSchedule(schedule="async", max_policy_lag=-1)
    assert schedule.before_episode(policy_version=-1, latest_ack_version=9) == ACT_NOW
    schedule.after_outcome(acted_with=3, newest_ack_version=7, superseded=True)
    assert schedule.min_version == 0 and not schedule.lockstep and not schedule.lag_bounded


def test_the_lag_bound_waits_for_an_arrival_when_the_latest_ack_asks_for_newer() -> None:
    schedule = WeightsSchedule(schedule="async", max_policy_lag=2)
    assert schedule.before_episode(policy_version=4, latest_ack_version=6) == Wait(
        Need.NEXT_ARRIVAL)
    assert schedule.before_episode(policy_version=6, latest_ack_version=6) == ACT_NOW
    # an ack's 0 asks for nothing (no bound at the replay yet), even before any weights
    assert schedule.before_episode(policy_version=-1, latest_ack_version=0) == ACT_NOW
    # a learner restarted from its checkpoint broadcasts lower versions again: the latest ack
    # (not the highest) decides, and the wait is for an arrival, never for a number
    assert schedule.before_episode(policy_version=2, latest_ack_version=3) == Wait(
        Need.NEXT_ARRIVAL)


def test_lockstep_waits_for_its_minimum_version_which_only_outcomes_raise() -> None:
    schedule = WeightsSchedule(schedule="lockstep", max_policy_lag=5)  # the bound is unused
    assert not schedule.lag_bounded
    # before the learner's first broadcast (version -1 at hand): wait for version 0
    assert schedule.before_episode(policy_version=-1, latest_ack_version=0) == Wait(
        Need.VERSION, 0)
    assert schedule.before_episode(policy_version=0, latest_ack_version=0) == ACT_NOW
    schedule.after_outcome(acted_with=0, newest_ack_version=1, superseded=False)  # cycle full
    assert schedule.before_episode(policy_version=0, latest_ack_version=1) == Wait(
        Need.VERSION, 1)
    # refused as stale or surplus: only newer weights can make the next episode wanted
    schedule.after_outcome(acted_with=3, newest_ack_version=1, superseded=True)
    assert schedule.min_version == 4
    # never lowered: a restarted learner's lower versions are waited out, not followed
    schedule.after_outcome(acted_with=4, newest_ack_version=2, superseded=False)
    assert schedule.min_version == 4
    assert schedule.before_episode(policy_version=5, latest_ack_version=0) == ACT_NOW
