"""The learner's loop as a pure object: cycles, epochs, weights versions and metrics rows.

`LearnerLoop.step(batch)` is the unit (Acme's `Learner.step()`): one `ServedBatch` of
`minibatches_per_cycle` minibatches → that many DDPG updates → one Polyak update → a new
weights version; every `cycles_per_epoch` cycles an epoch ends, its row taking the replay's
counters of the moment its last batch was drawn (`replay_status`), and `record_eval`
completes that row. The service runs it in a loop; tests drive it directly.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hercs.errors import Diverged
from hercs.learner.ddpg import DDPGLearner
from hercs.wire.served import ReplayCounters, ServedBatch


@dataclass
class CycleResult:
    version: int
    """Weights version after this cycle's updates (broadcast it)."""
    epoch_ended: int | None
    """The epoch (1-based) that this cycle completed, else None."""


@dataclass
class EpochSnapshot:
    """Training-side figures at the end of an epoch, waiting for its evaluation."""

    epoch: int
    version: int
    env_steps: int
    inserts: int
    updates: int
    wall_s: float
    env_steps_per_s: float
    updates_per_s: float
    policy_lag: float
    cluster_model_version: int
    cluster_share: list[float]
    losses: dict[str, float]
    policy_lag_request: float = 0.0
    policy_lag_p50: float = float("nan")
    policy_lag_p95: float = float("nan")
    policy_lag_max: float = float("nan")
    sampled_moved_share: float = float("nan")
    buffer_moved_share: float = float("nan")
    replay_size: int = 0
    """Transitions stored at the epoch's last batch."""
    cluster_sizes: list[int] = field(default_factory=list)
    rejects: dict[str, int] = field(default_factory=dict)


class LearnerLoop:
    def __init__(self, *, learner: DDPGLearner, epochs: int, cycles_per_epoch: int,
                 clusters: int, replay_status: Callable[[int], ReplayCounters],
                 clock=time.monotonic) -> None:
        """`epochs` to train, `cycles_per_epoch` batches to an epoch, `clusters` the k whose
        draws each epoch's row reports (hercs.learner.builder unpacks them from the config);
        `replay_status(samples_served)`: the replay's counters when the batch that ended at
        that count was drawn (hercs.learner.replay_status over the wire)."""
        self.epochs = epochs
        self.replay_status = replay_status
        self.cycles_per_epoch = cycles_per_epoch
        self.learner = learner
        self.clock = clock
        self.cycle = 0
        self.version = 0
        """Weights version: 0 = initial weights, +1 per cycle."""
        self.epoch = 0
        self._start = clock()
        self._epoch_start = self._start
        self._epoch_start_steps = 0
        self._epoch_start_updates = 0
        self._epoch_draws = np.zeros(clusters, np.int64)
        self._epoch_lags: list[np.ndarray] = []
        self._epoch_moved = np.zeros(2, np.int64)  # sampled moved, sampled transitions
        self._epoch_buffer_share: list[float] = []
        self._last: ServedBatch | None = None
        self.pending: dict[int, EpochSnapshot] = {}

    @property
    def done(self) -> bool:
        return self.epoch >= self.epochs

    def state_dict(self) -> dict[str, Any]:
        """Where the loop stands, taken at an epoch end (what a resumed learner continues
        from); the learner's own state is `DDPGLearner.state_dict()`."""
        return {
            "cycle": self.cycle, "version": self.version, "epoch": self.epoch,
            "wall_s": self.clock() - self._start,
            "epoch_start_steps": self._epoch_start_steps,
            "epoch_start_updates": self._epoch_start_updates,
            "pending": {e: dataclasses.asdict(s) for e, s in self.pending.items()},
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Continue from `state_dict()`: counters, the run's wall time so far, and the
        epochs still waiting for their evaluation."""
        self.cycle, self.version, self.epoch = (int(state[k]) for k in ("cycle", "version",
                                                                        "epoch"))
        now = self.clock()
        self._start = now - float(state["wall_s"])
        self._epoch_start = now
        self._epoch_start_steps = int(state["epoch_start_steps"])
        self._epoch_start_updates = int(state["epoch_start_updates"])
        self.pending = {int(e): EpochSnapshot(**s) for e, s in state["pending"].items()}

    def step(self, batch: ServedBatch) -> CycleResult:
        """One cycle: adopt the replay's normaliser stats, update on every minibatch, update
        the targets, bump the version. A loss or a weight that is no longer finite raises
        `Diverged` naming the epoch, the cycle, the update and the value, before the targets
        or the version change (so nothing of that cycle can be published or saved)."""
        self.learner.set_normalizer_state(batch.o_stats, batch.g_stats)
        first_update = self.learner.updates + 1
        try:
            for minibatch in batch.minibatches:
                self.learner.train(minibatch)  # losses summed on the device, read at epoch end
            # before the targets average the weights in and before anyone publishes them
            self.learner.check_finite(first_update=first_update)
        except Diverged as exc:
            raise self.diverged(exc) from None
        self.learner.update_targets()
        return self.account(batch)

    def diverged(self, exc: Diverged) -> Diverged:
        """`exc` (what turned non-finite in the learner) placed in this cycle of the run."""
        cycles = self.cycles_per_epoch
        return Diverged(f"training diverged in epoch {self.epoch + 1}, cycle "
                        f"{self.cycle % cycles + 1} of {cycles} (the run's cycle "
                        f"{self.cycle + 1}), {exc}")

    def account(self, batch: ServedBatch) -> CycleResult:
        """The cycle's bookkeeping once its updates and the targets' are done (by `step`, or
        by a stack of learners, hercs.learner.stacked_cells): a new version, the epoch's
        draws, lags and moved shares, and the epoch's snapshot when it ends."""
        self.version += 1
        self.cycle += 1
        if batch.cluster_draws.shape == self._epoch_draws.shape:
            self._epoch_draws += batch.cluster_draws
        self._epoch_lags.append(batch.policy_lags)
        self._epoch_moved += (batch.sampled_moved, batch.sampled_transitions)
        if batch.sampled_transitions:
            self._epoch_buffer_share.append(batch.buffer_moved_share)
        self._last = batch
        ended = None
        if self.cycle % self.cycles_per_epoch == 0:
            self.epoch += 1
            ended = self.epoch
            self.pending[self.epoch] = self._snapshot()
        return CycleResult(self.version, ended)

    def _snapshot(self) -> EpochSnapshot:
        now = self.clock()
        batch = self._last
        assert batch is not None
        elapsed = max(now - self._epoch_start, 1e-9)
        updates = self.learner.updates
        draws = self._epoch_draws
        share = (draws / draws.sum()).tolist() if draws.sum() else [0.0] * len(draws)
        losses = self.learner.loss_means()
        lags = np.concatenate(self._epoch_lags) if self._epoch_lags else np.zeros(0)
        p50, p95, top = ((float(np.percentile(lags, 50)), float(np.percentile(lags, 95)),
                          float(lags.max())) if lags.size else (float("nan"),) * 3)
        moved, sampled = (int(v) for v in self._epoch_moved)
        status = self.replay_status(batch.samples_served)
        snap = EpochSnapshot(
            epoch=self.epoch, version=self.version, env_steps=status.env_steps,
            inserts=status.inserts, updates=updates, wall_s=now - self._start,
            env_steps_per_s=(status.env_steps - self._epoch_start_steps) / elapsed,
            updates_per_s=(updates - self._epoch_start_updates) / elapsed,
            policy_lag=status.policy_lag, cluster_model_version=status.cluster_model_version,
            cluster_share=share, losses=losses, policy_lag_request=status.policy_lag_request,
            policy_lag_p50=p50, policy_lag_p95=p95, policy_lag_max=top,
            sampled_moved_share=moved / sampled if sampled else float("nan"),
            buffer_moved_share=(float(np.mean(self._epoch_buffer_share))
                                if self._epoch_buffer_share else float("nan")),
            replay_size=status.size_transitions, cluster_sizes=list(status.cluster_sizes),
            rejects=dict(status.rejects),
        )
        self._epoch_lags, self._epoch_moved = [], np.zeros(2, np.int64)
        self._epoch_buffer_share = []
        self._epoch_start, self._epoch_start_steps = now, status.env_steps
        self._epoch_start_updates = updates
        self._epoch_draws = np.zeros_like(self._epoch_draws)
        return snap

    def record_eval(self, *, epoch: int, success_rate: float,
                    mean_final_distance: float) -> dict[str, Any] | None:
        """Complete epoch `epoch`'s metrics row; None if that epoch is unknown or done."""
        snap = self.pending.pop(epoch, None)
        if snap is None:
            return None
        return {
            "epoch": snap.epoch, "env_steps": snap.env_steps, "episodes": snap.inserts,
            "updates": snap.updates, "success_rate": success_rate,
            "mean_final_distance": mean_final_distance, "wall_s": round(snap.wall_s, 3),
            "env_steps_per_s": round(snap.env_steps_per_s, 2),
            "updates_per_s": round(snap.updates_per_s, 2),
            "replay_size": snap.replay_size,
            "policy_lag": round(snap.policy_lag, 3), "weights_version": snap.version,
            "policy_lag_request": round(snap.policy_lag_request, 3),
            "policy_lag_p50": snap.policy_lag_p50, "policy_lag_p95": snap.policy_lag_p95,
            "policy_lag_max": snap.policy_lag_max,
            "sampled_moved_share": round(snap.sampled_moved_share, 4),
            "buffer_moved_share": round(snap.buffer_moved_share, 4),
            "cluster_model_version": snap.cluster_model_version,
            "cluster_sizes": ";".join(str(c) for c in snap.cluster_sizes),
            "cluster_share": ";".join(f"{s:.4f}" for s in snap.cluster_share),
            "rejects": ";".join(f"{k}:{v}" for k, v in sorted(snap.rejects.items())),
            "critic_loss": round(snap.losses.get("critic_loss", float("nan")), 6),
            "actor_loss": round(snap.losses.get("actor_loss", float("nan")), 6),
            "q_mean": round(snap.losses.get("q_mean", float("nan")), 6),
        }
