"""Where a running epoch stands, from the learner's `RunProgress` (its cycles and updates, put
after every cycle): the numbers of `hercs up`'s live line, pure, with an injected clock."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from hercs.proto import hercs_pb2 as pb


def duration(seconds: float) -> str:
    """1h02m, 3m20s or 45s."""
    seconds = max(round(seconds), 0)
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours}h{minutes:02d}m"
    return f"{minutes}m{secs:02d}s" if minutes else f"{secs}s"


class CycleCounter:
    """The learner's cycle and update counts as they arrive, and the cycle rate since the first
    one this launcher saw, from which the time left to a later cycle follows."""

    def __init__(self, *, clock: Callable[[], float]) -> None:
        self._clock = clock
        self.cycle: int | None = None
        """Cycles the learner has completed in the run (None: it has not said)."""
        self.cycles_per_epoch = 0
        self.updates: int | None = None
        self._first: tuple[float, int] | None = None
        """(time, cycle) where the rate's window starts."""
        self._last: tuple[float, int] | None = None
        """(time, cycle) of the newest cycle count that changed."""

    def on_run_progress(self, progress: pb.RunProgress) -> None:
        if not progress.cycles_per_epoch:  # a learner that counts no cycles
            return
        now, cycle = self._clock(), int(progress.cycle)
        self.cycles_per_epoch = int(progress.cycles_per_epoch)
        self.updates = int(progress.updates)
        if self._first is None or self.cycle is None or cycle < self.cycle:
            # the first count, or a restarted learner back at its checkpoint: a new window
            self._first = (now, cycle)
            self._last = (now, cycle)
        elif cycle != self.cycle:
            self._last = (now, cycle)
        self.cycle = cycle

    @property
    def running_epoch(self) -> int | None:
        """The epoch the next cycle belongs to (None before the learner's first count)."""
        if self.cycle is None:
            return None
        return self.cycle // self.cycles_per_epoch + 1

    def cycle_in_epoch(self, epoch: int) -> int | None:
        """Cycles of `epoch` done, 0 to `cycles_per_epoch` (None before the first count)."""
        if self.cycle is None:
            return None
        done = self.cycle - (epoch - 1) * self.cycles_per_epoch
        return min(max(done, 0), self.cycles_per_epoch)

    def eta_s(self, cycle: int) -> float | None:
        """Seconds until the learner reaches `cycle` at the rate seen so far (0 once there);
        None until two counts apart in time give a rate."""
        if self._first is None or self._last is None or self.cycle is None:
            return None
        if cycle <= self.cycle:
            return 0.0
        (t0, c0), (t1, c1) = self._first, self._last
        if c1 <= c0 or t1 <= t0:
            return None
        rate = (c1 - c0) / (t1 - t0)
        return max((cycle - c1) / rate - (self._clock() - t1), 0.0)


@dataclass(frozen=True)
class LiveStatus:
    """One moment of a running epoch, as the live line shows it."""

    epoch: int
    epochs: int
    cycle: int | None
    """Cycles of this epoch done (None: the learner has not said yet)."""
    cycles_per_epoch: int
    env_steps: int | None
    """The replay's env steps in the run so far."""
    updates: int | None
    actors: int | None
    waiting_for_actors: bool
    epoch_eta_s: float | None
    run_eta_s: float | None
    since_start_s: float

    @property
    def fraction(self) -> float:
        """The share of this epoch's cycles done (0 before any count)."""
        if self.cycle is None or not self.cycles_per_epoch:
            return 0.0
        return self.cycle / self.cycles_per_epoch

    def text(self) -> str:
        """`epoch 2/3  cycle 31/50  env 15500 steps  updates 1240  actors 2  eta 12s epoch,
        1m40s run` (the parts not known yet left out)."""
        parts = [f"epoch {self.epoch}/{self.epochs}"]
        if self.cycle is not None:
            parts.append(f"cycle {self.cycle}/{self.cycles_per_epoch}")
        if self.env_steps is not None:
            parts.append(f"env {self.env_steps} steps")
        if self.updates is not None:
            parts.append(f"updates {self.updates}")
        if self.waiting_for_actors:
            parts.append("waiting for remote actors")
        elif self.actors is not None:
            parts.append(f"actors {self.actors}")
        if self.epoch_eta_s is not None and self.run_eta_s is not None:
            parts.append(f"eta {duration(self.epoch_eta_s)} epoch, "
                         f"{duration(self.run_eta_s)} run")
        else:
            parts.append(f"{duration(self.since_start_s)} since start")
        return "  ".join(parts)
