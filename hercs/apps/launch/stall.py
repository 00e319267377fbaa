"""When a run has stopped moving: the stall bound of `hercs up` (hercs/apps/launch/supervisor.py).

A run that ends no epoch for `launch.stall_factor` times its slowest epoch so far (before the
first, times `expected_first_epoch_s`), or for a day (`MAX_STALL_S`) whichever is shorter,
has stalled, whatever the cause; nothing else would end it, since each service waits,
correctly, for another (a service stopped but alive, a learner whose weights every actor
refuses, a replay that holds every request). The bound follows the run's own pace, so a slow
machine or a heavy task is judged by itself; the slowest epoch includes the first, which
includes starting every service, so a restart mid-run costs less than the bound. The cap: the
first-epoch estimate grows with the config (a batch of 10^9 rows made it 922 days); a run whose
epochs take longer sets `launch.stall_factor=0`. The reference machine's speeds it predicts
the first epoch from, and the cap, are hercs.config.limits' (the config's bounds use them
too). Pure bookkeeping with an injected clock; the supervisor feeds it and asks `stalled()`.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from hercs.config import HercsConfig
from hercs.config.limits import ENV_STEP_S, MAX_STALL_S, STARTUP_S, UPDATE_S


def expected_first_epoch_s(config: HercsConfig) -> float:
    """What the first epoch of `config` costs on the development machine, counted as if
    nothing ran in parallel (every actor and the learner on one core): the services'
    start, the epoch's DDPG updates and the env steps of its episodes and evaluation."""
    training, ddpg = config.training, config.ddpg
    update_s = UPDATE_S * (ddpg.batch_size / 256) * (ddpg.hidden_size / 256) ** 2 * (
        ddpg.hidden_layers / 3)
    updates = training.cycles_per_epoch * training.minibatches_per_cycle
    steps = (training.episodes_per_epoch + training.eval_episodes) * (
        config.task.spec.episode_steps)
    return STARTUP_S + updates * update_s + steps * ENV_STEP_S


class StallWatch:
    """How long since the run last moved, against its bound.

    `begin()` starts the clock (when the run's actors can act: at once with local actors,
    at the first remote actor's arrival without); `hold()` stops it while a run of remote
    actors has none (a node that died, a host that left: waiting for actors is the scheduler's
    or the user's business, not a stall) and the next `begin()` starts it afresh;
    `epoch_ended(epoch)` is a move, timed against the last; `episode_stored()` is noted for
    the report but is not a move (actors may store episodes for a learner that never finishes
    an epoch).
    """

    def __init__(self, *, factor: float, first_epoch_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.factor = factor
        self.first_epoch_s = first_epoch_s
        self._clock = clock
        self.since: float | None = None
        """When the clock began, or the last epoch ended; None before `begin()`."""
        self.slowest_s: float | None = None
        """The slowest epoch this watch has timed."""
        self.last_epoch: int | None = None
        self.last_episode_at: float | None = None

    def begin(self) -> None:
        """Start the clock; later calls change nothing."""
        if self.since is None:
            self.since = self._clock()

    def hold(self) -> None:
        """Stop the clock until the next `begin()`: no actor can act."""
        self.since = None

    def epoch_ended(self, epoch: int) -> None:
        """Epoch `epoch` ended now (a repeated or older epoch is not a move)."""
        if self.last_epoch is not None and epoch <= self.last_epoch:
            return
        now = self._clock()
        if self.since is not None:
            took = now - self.since
            self.slowest_s = took if self.slowest_s is None else max(self.slowest_s, took)
        self.since, self.last_epoch = now, epoch

    def episode_stored(self) -> None:
        self.last_episode_at = self._clock()

    @property
    def bound_s(self) -> float:
        """Seconds without an epoch's end after which the run has stalled: the factor times
        the pace, at most `MAX_STALL_S` (the first-epoch estimate grows with the config)."""
        return min(self.factor * self._pace_s, MAX_STALL_S)

    @property
    def _pace_s(self) -> float:
        return self.slowest_s if self.slowest_s is not None else self.first_epoch_s

    def quiet_s(self) -> float:
        """Seconds since the clock began or the last epoch ended (0 before `begin()`)."""
        return 0.0 if self.since is None else self._clock() - self.since

    def stalled(self) -> bool:
        """True once the run has gone `bound_s` without an epoch's end (never with factor 0
        or before `begin()`)."""
        return self.factor > 0 and self.since is not None and self.quiet_s() >= self.bound_s

    def describe(self) -> str:
        """What stalled, since when, and the bound it passed, in a sentence."""
        since = (f"since epoch {self.last_epoch} ended" if self.last_epoch is not None
                 else "since the run began")
        pace = (f"the slowest epoch so far, {self.slowest_s:.1f} s" if self.slowest_s is not None
                else f"the first epoch this config should take at most, "
                     f"{self.first_epoch_s:.0f} s")
        if self.last_episode_at is None:
            episodes = "no episode has been stored since the run began"
        else:
            ago = self._clock() - self.last_episode_at
            episodes = (f"the last episode was stored {ago:.0f} s ago" if ago >= 1
                        else "episodes are still being stored")
        capped = (f", capped at {MAX_STALL_S:.0f} s (a day)"
                  if self.factor * self._pace_s > MAX_STALL_S else "")
        return (f"no epoch has ended for {self.quiet_s():.0f} s ({since}); the bound is "
                f"launch.stall_factor {self.factor:g} x {pace}{capped}; {episodes}")
