"""Where a sweep stands: its cells done, running and left, and the time left at the pace of the
runs this call has finished (the `[sweep]` line `hercs sweep` prints at each change)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from hercs.apps.launch.epoch_progress import duration


@dataclass
class SweepTally:
    """Counts of one `hercs sweep` call's cells; `line` says them."""

    total: int
    jobs: int
    done: int = 0
    """Finished cells: earlier (skipped) or by this call."""
    failed: int = 0
    walls: list[float] = field(default_factory=list)
    """Seconds each run this call started from the beginning took to finish (a resumed run's
    time covers only its rest, and says less of the next run's)."""
    resumed_walls: list[float] = field(default_factory=list)

    def finished(self, wall_s: float, *, resumed: bool) -> None:
        self.done += 1
        (self.resumed_walls if resumed else self.walls).append(wall_s)

    def eta_s(self, *, left: int, running_s: Sequence[float]) -> float | None:
        """Seconds until every cell is run, `jobs` at a time: the mean finished run for each
        cell left, less what each running one has done; None before any run has finished."""
        walls = self.walls or self.resumed_walls
        if not walls:
            return None
        mean = sum(walls) / len(walls)
        work = left * mean + sum(max(mean - elapsed, 0.0) for elapsed in running_s)
        return work / max(min(self.jobs, left + len(running_s)), 1)

    def line(self, *, left: int, running_s: Sequence[float]) -> str:
        """`[sweep] 3 of 12 done, 2 running, 7 left; eta 1h10m (21m a run, 2 at a time)`."""
        failed = f" ({self.failed} failed, resumed by the next call)" if self.failed else ""
        counts = (f"[sweep] {self.done} of {self.total} done, {len(running_s)} running, "
                  f"{left} left{failed}")
        if not left and not running_s:
            return counts
        eta = self.eta_s(left=left, running_s=running_s)
        if eta is None:
            return f"{counts}; eta once the first run ends"
        walls = self.walls or self.resumed_walls
        return (f"{counts}; eta {duration(eta)} ({duration(sum(walls) / len(walls))} a run, "
                f"{self.jobs} at a time)")
