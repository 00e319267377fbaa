"""The progress lines of `hercs up`: one per evaluated epoch, one while an epoch runs long, and
those that end a finished run, from what the learner, evaluator, replay and clusterer publish.

Pure bookkeeping with an injected clock. For a cluster method each epoch line carries the
cluster model and its episodes per cluster, or, before the first model, the failed goals
counted towards it; a run that ends without a model says why (a policy that rarely fails, as
on FetchReach, gives too few failed goals).
"""

from __future__ import annotations

import shlex
import time
from collections import Counter
from collections.abc import Callable, Mapping
from pathlib import Path

from hercs.apps.launch.epoch_progress import CycleCounter, LiveStatus, duration
from hercs.config import HercsConfig
from hercs.proto import hercs_pb2 as pb


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


FIRST_LINE_S = 5.0
"""The first progress line comes this long after the run starts (before epoch 1 ends)."""
INTERIM_EVERY_S = 60.0
"""While an epoch runs, a progress line at least this often."""
RARELY_FAILS = 0.9
"""An evaluated success from which the end of a run without a cluster model names the
policy's success as the reason so few goals failed."""


class Progress:
    """Turns the learner's per-epoch `Metrics` (and `EvalResult`s) into one line per epoch.

    Pure bookkeeping, no I/O: each method returns the lines now ready, in epoch order. A line
    without `success_rate` waits for its epoch's `EvalResult` until a later epoch's metrics
    arrive (or `flush()`); each epoch is printed once.
    """

    def __init__(self, total_epochs: int, *, fit_size: int | None = None,
                 first_epoch: int = 1, remote_actors_only: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """`fit_size`: the failed goals the first cluster model needs (`cluster.fgb_size`);
        None for a method without clusters, whose lines say nothing of them. `first_epoch`:
        the epoch this launcher sees run first (a resumed run's, after its checkpoint).
        `remote_actors_only`: the run starts no actor (`--actors 0`), so it waits for remote
        ones while none is seen."""
        self.total_epochs = total_epochs
        self.fit_size = fit_size
        self.first_epoch = first_epoch
        self.remote_actors_only = remote_actors_only
        self.cycles = CycleCounter(clock=clock)
        """The learner's cycles and updates within the epoch (its `RunProgress`)."""
        self._env_steps: int | None = None
        """The replay's env steps so far (its `ReplayStatus`)."""
        self._cluster_version = 0
        self._cluster_sizes: list[int] = []
        self._status_seen = False
        self._clusterer: dict[str, float] = {}
        """The clusterer's latest `Metrics` (failed_goals_seen, episodes_seen, …)."""
        self.last_printed = 0
        self._pending: dict[int, dict[str, float]] = {}
        self._success: dict[int, float] = {}
        self._replay_size: float | None = None
        self.restarts = 0
        """Children restarted so far (shown on the line when not 0)."""
        self.bad_episodes = 0
        self._printed: dict[int, float | None] = {}
        """Epochs whose line was printed, with the success it said (None: `success -`)."""
        """Inserts the replay refused as bad input so far (the learner's `bad_episodes`)."""
        self.actors: int | None = None
        """Actors whose liveliness token the router sees (local and remote)."""
        self._episodes_by_actor: Counter[str] = Counter()
        """Episodes stored per actor since the last epoch line (from replay/inserted)."""
        self._clock = clock
        self.started = clock()
        self.last_line_at: float | None = None
        self._first_epoch: int | None = None  # the first epoch this launcher saw (resume)

    @classmethod
    def for_run(cls, config: HercsConfig, *, first_epoch: int = 1) -> Progress:
        """The progress of the run `config` describes, from `first_epoch` on."""
        return cls(config.training.epochs,
                   fit_size=config.cluster.fgb_size if config.run.uses_clusters else None,
                   first_epoch=first_epoch, remote_actors_only=config.actor.num_actors == 0)

    @property
    def running_epoch(self) -> int:
        """The epoch training is in now: the learner's cycle count says it once it has spoken;
        before, the one after the last printed (or the resumed run's first)."""
        told = self.cycles.running_epoch
        return min(max(self.last_printed + 1, self.first_epoch, told or 0), self.total_epochs)

    @property
    def waiting_for_actors(self) -> bool:
        """A run of remote actors only, none of which the router sees now."""
        return self.remote_actors_only and not self.actors

    def on_run_progress(self, progress: pb.RunProgress) -> None:
        """The learner's `RunProgress`: its cycles and updates so far."""
        self.cycles.on_run_progress(progress)

    def live_status(self) -> LiveStatus:
        """What the live line shows now: the running epoch's cycles, the env steps and
        updates so far, the actors, and the time left in the epoch and the run."""
        epoch = self.running_epoch
        counter = self.cycles
        return LiveStatus(
            epoch=epoch, epochs=self.total_epochs, cycle=counter.cycle_in_epoch(epoch),
            cycles_per_epoch=counter.cycles_per_epoch, env_steps=self._env_steps,
            updates=counter.updates, actors=self.actors,
            waiting_for_actors=self.waiting_for_actors,
            epoch_eta_s=counter.eta_s(epoch * counter.cycles_per_epoch),
            run_eta_s=counter.eta_s(self.total_epochs * counter.cycles_per_epoch),
            since_start_s=self._clock() - self.started)

    def interim(self) -> str | None:
        """A line for an epoch still running: the first `FIRST_LINE_S` after start (so a
        user sees the run is alive long before epoch 1 ends), then whenever no line was
        printed for `INTERIM_EVERY_S`; None otherwise."""
        now = self._clock()
        quiet_since = self.last_line_at if self.last_line_at is not None else (
            self.started - INTERIM_EVERY_S + FIRST_LINE_S)
        if now - quiet_since < INTERIM_EVERY_S:
            return None
        self.last_line_at = now
        epoch = self.running_epoch
        return (f"epoch {epoch}/{self.total_epochs} running  {duration(now - self.started)} "
                f"since start  replay {_fmt(self._replay_size, '.0f')} episodes"
                + (f"  actors {self.actors}" if self.actors is not None else "")
                + ("  waiting for remote actors" if self.waiting_for_actors else "")
                + (f"  restarts {self.restarts}" if self.restarts else "")
                + self._bad_text())

    def _bad_text(self) -> str:
        """The episodes the replay has refused as bad input so far (malformed, implausible:
        hercs.rl.plausibility), where there are any."""
        bad = self.bad_episodes
        return f"  refused {bad} bad episode{'s' if bad != 1 else ''}" if bad else ""

    def on_metrics(self, service: str, values: Mapping[str, float]) -> list[str]:
        if service.startswith("clusterer/"):
            self._clusterer = dict(values)
            return []
        if not service.startswith("learner/") or "epoch" not in values:
            return []
        epoch = int(values["epoch"])
        if epoch < self.last_printed or epoch in self._printed:
            return self._late(epoch, values)
        self._pending[epoch] = dict(values)
        return self._release(final=False)

    def _late(self, epoch: int, values: Mapping[str, float]) -> list[str]:
        """An epoch whose evaluation came after a later epoch's line (an evaluator restarted
        mid-epoch): its success said once, not dropped; nothing for a repeat."""
        success = values.get("success_rate")
        if success is None or self._printed.get(epoch) is not None:
            return []
        self._printed[epoch] = float(success)
        self._success[epoch] = float(success)
        return [f"epoch {epoch}/{int(values.get('epochs', self.total_epochs))}  success "
                f"{_fmt(success, '.2f')}  (evaluated late, after epoch {self.last_printed})"]

    def on_eval(self, epoch: int, success_rate: float) -> list[str]:
        if epoch in self._printed:
            return self._late(epoch, {"success_rate": success_rate})
        self._success[epoch] = success_rate
        return self._release(final=False)

    def on_replay_status(self, status: pb.ReplayStatus) -> None:
        """The replay's latest status: its size, and its cluster model with the episodes it
        holds per cluster."""
        self._replay_size = status.size_episodes
        self._env_steps = int(status.env_steps)
        self._cluster_version = int(status.cluster_model_version)
        self._cluster_sizes = [int(n) for n in status.cluster_sizes]
        self._status_seen = True

    def on_inserted(self, actor_id: str) -> None:
        """One more episode stored, from `actor_id` (its share shows on the next line)."""
        self._episodes_by_actor[actor_id] += 1

    def _actors_text(self) -> str:
        """`  actors N`, with each actor's share of the episodes since the last line when
        more than one actor contributed (in actor-id order), e.g. `  actors 2 (61/39 %)`."""
        if self.actors is None:
            return ""
        counts = [n for _, n in sorted(self._episodes_by_actor.items())]
        self._episodes_by_actor.clear()
        if len(counts) < 2:
            return f"  actors {self.actors}"
        total = sum(counts)
        shares = "/".join(f"{round(100 * n / total)}" for n in counts)
        return f"  actors {self.actors} ({shares} %)"

    def _failed_goals(self) -> int | None:
        seen = self._clusterer.get("failed_goals_seen")
        return None if seen is None else int(seen)

    def _clusters_text(self) -> str:
        """`  clusters v3 [60 0 56 0]` (the model the replay uses, its episodes per cluster),
        `  clusters none yet (12/150 failed goals)`, or "" for a method without clusters."""
        if self.fit_size is None:
            return ""
        if self._cluster_version > 0:
            sizes = " ".join(str(n) for n in self._cluster_sizes)
            return f"  clusters v{self._cluster_version} [{sizes}]"
        failed = self._failed_goals()
        counted = "" if failed is None else f" ({min(failed, self.fit_size)}/{self.fit_size} " \
                                            "failed goals)"
        return f"  clusters none yet{counted}"

    def finished_lines(self, run_name: str, run_dir: Path) -> list[str]:
        """The lines that end a finished run: for a cluster method that never had a model,
        why; last, the run's folder and the command that shows its episodes (and clusters)."""
        lines = []
        shows = "its episodes"
        if self.fit_size is not None:
            if self._cluster_version > 0 or not self._status_seen:
                shows = "its episodes and clusters"
            else:
                lines.append(f"hercs up: {self._why_no_model()}")
        return [*lines, f"hercs up: run {run_name} finished; run directory: {run_dir}; "
                        f"{shows}: hercs view {shlex.quote(str(run_dir))}"]

    def _why_no_model(self) -> str:
        """`no cluster model: 12 failed goals in 400 episodes, a fit needs …`."""
        failed = self._failed_goals()
        episodes = self._clusterer.get("episodes_seen")
        counted = ("the clusterer reported no count of failed goals" if failed is None else
                   f"{failed} failed goal{'s' if failed != 1 else ''}"
                   + ("" if episodes is None else f" in {int(episodes)} episodes"))
        solved = [e for e, rate in sorted(self._success.items()) if rate >= RARELY_FAILS]
        reason = (f" (its evaluated success reached {self._success[solved[0]]:.2f} at epoch "
                  f"{solved[0]}, so few episodes failed)" if solved else "")
        return (f"no cluster model: {counted}, a fit needs cluster.fgb_size={self.fit_size}"
                f"{reason}; a longer run or a smaller --set cluster.fgb_size=N fits one")

    def flush(self) -> list[str]:
        """Every line still waiting, with `success -` where no result came."""
        return self._release(final=True)

    def _release(self, *, final: bool) -> list[str]:
        lines = []
        for epoch in sorted(self._pending):
            values = self._pending[epoch]
            has_success = "success_rate" in values or epoch in self._success
            later = any(e > epoch for e in self._pending)
            if not (has_success or later or final):
                break
            del self._pending[epoch]
            lines.append(self._line(epoch, values))
            self._printed[epoch] = self._success.get(epoch)
            self.last_printed = epoch
        return lines

    def _line(self, epoch: int, values: Mapping[str, float]) -> str:
        now = self._clock()
        total = int(values.get("epochs", self.total_epochs))
        success = values.get("success_rate", self._success.get(epoch))
        if success is not None:
            self._success[epoch] = success
        replay = values.get("replay_size", self._replay_size)
        self.bad_episodes = int(values.get("bad_episodes", self.bad_episodes) or 0)
        if self._first_epoch is None:
            self._first_epoch = epoch
        done_here = epoch - self._first_epoch + 1  # epochs this launcher watched end
        eta = (now - self.started) / done_here * (total - epoch) if done_here > 0 else None
        self.last_line_at = now
        return (f"epoch {epoch}/{total}  success {_fmt(success, '.2f')}  "
                f"env {_fmt(values.get('env_steps_per_s'), '.0f')} steps/s  "
                f"upd {_fmt(values.get('updates_per_s'), '.0f')}/s  "
                f"replay {_fmt(replay, '.0f')}  lag {_fmt(values.get('policy_lag'), '.1f')}"
                + self._actors_text() + self._clusters_text()
                + (f"  eta {duration(eta)}" if eta is not None and epoch < total else "")
                + (f"  restarts {self.restarts}" if self.restarts else "")
                + self._bad_text())
