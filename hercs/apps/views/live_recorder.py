"""The live view's core (`hercs live`, views/live_view.py): a run's decoded messages in, the
entities of `hercs view` out, drawn with views/rerun_draw.py. No Zenoh here: the shell
subscribes, parses and queries; tests drive `LiveRecorder` with messages directly.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from hercs.apps.views.rerun_draw import (
    EpisodeOutcome,
    LoggedModel,
    declare_curve,
    log_centroids,
    log_episode,
    log_episode_scalars,
    log_failed_goals,
    log_world,
    summarize_episode,
)
from hercs.errors import ConfigError, InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.task_registry import TaskSpec
from hercs.wire.codec import msg_to_cluster_model
from hercs.wire.validation import header_goals, validate_centroids

MAX_FAILED_GOALS = 2000
"""`world/failed_goals` shows at most this many, the newest (the FGB holds 150 by default)."""
_NOT_CURVES = frozenset({"epoch", "epochs"})


def header_outcome(header: pb.EpisodeHeader, spec: TaskSpec) -> EpisodeOutcome:
    """An `EpisodeHeader` as `hercs view` summarises an episode: success by the task's rule
    (`TaskSpec.is_success`). Raises `InvalidMessage` for a missing, misshapen or non-finite goal,
    or a cluster below −1."""
    final_ag, desired_goal = (v.astype(np.float32)
                              for v in header_goals(header, goal_dim=spec.goal_dim))
    if header.cluster < -1:
        raise InvalidMessage(Reason.BAD_VALUE,
                             f"EpisodeHeader.cluster {header.cluster}, must be >= -1")
    distance = float(np.linalg.norm(final_ag - desired_goal))
    return EpisodeOutcome(
        episode_id=int(header.episode_id),
        success=bool(spec.is_success(final_ag, desired_goal)),
        final_distance=distance, cluster=int(header.cluster), desired_goal=desired_goal,
        actor_id=header.actor_id, seq=int(header.seq), policy_version=int(header.policy_version))


class LiveRecorder:
    """Turns a run's messages, as they arrive, into the entities of `hercs view`.

    Single-threaded (the shell's main loop calls it). Every `on_*` method starts from a clean
    time cursor (`reset_time`), so no timeline leaks from one message into the next. The
    per-episode scalars are buffered and sent in one batch by `commit()`.
    """

    def __init__(self, rr: Any, rec: Any, *, spec: TaskSpec, k: int, episode_every: int,
                 max_failed_goals: int = MAX_FAILED_GOALS) -> None:
        if episode_every < 0:
            raise ConfigError(f"episode_every: got {episode_every!r}, must be >= 0 (0 = none)")
        if max_failed_goals < 1:
            raise ConfigError(f"max_failed_goals: got {max_failed_goals!r}, must be >= 1")
        self.rr = rr
        self.rec = rec
        self.spec = spec
        self.k = k
        self.episode_every = episode_every
        self.headers = 0
        self.trajectories = 0
        self.models = 0
        self.epochs = 0
        self._pending: list[EpisodeOutcome] = []
        self._styled = False
        self._wanted: dict[int, int] = {}  # episode id → its cluster, until the episode arrives
        self._failed: deque[np.ndarray] = deque(maxlen=max_failed_goals)
        self._centroids: np.ndarray | None = None
        self._model_version = 0
        self._early_model: ClusterModel | None = None  # came before any header
        self._last_episode = -1
        self._last_epoch = 0
        self._curves: set[str] = set()
        self._cluster_sizes: list[float] = []

    def start(self) -> None:
        """The static world frame (as `hercs view`)."""
        log_world(self.rr, self.rec)

    # -- episodes --------------------------------------------------------------------------
    def wants(self, episode_id: int) -> bool:
        """True for the ids whose trajectory is drawn (multiples of `episode_every`)."""
        return self.episode_every > 0 and episode_id % self.episode_every == 0

    def on_header(self, header: pb.EpisodeHeader) -> bool:
        """One stored episode. True if its trajectory should be fetched and given to
        `on_episode` (the failed goals are logged at its id right away)."""
        outcome = header_outcome(header, self.spec)
        self.rec.reset_time()
        self.headers += 1
        self._pending.append(outcome)
        self._last_episode = max(self._last_episode, outcome.episode_id)
        if not outcome.success:
            self._failed.append(outcome.desired_goal)
        if self._early_model is not None:
            self._log_model(self._early_model, at_episode=outcome.episode_id)
            self._early_model = None
        if not self.wants(outcome.episode_id):
            return False
        self._wanted[outcome.episode_id] = outcome.cluster
        self._log_failed_goals(outcome.episode_id)
        return True

    def on_episode(self, msg: pb.Episode, *, episode_id: int) -> None:
        """The full episode of a wanted id (validated against the task by the caller)."""
        cluster = self._wanted.pop(episode_id, -1)
        self.rec.reset_time()
        log_episode(self.rr, self.rec, summarize_episode(msg, episode_id=episode_id,
                                                         spec=self.spec, cluster=cluster))
        self.rec.reset_time()
        self.trajectories += 1

    def forget(self, episode_id: int) -> None:
        """A wanted episode that could not be fetched."""
        self._wanted.pop(episode_id, None)

    def commit(self) -> None:
        """Send the buffered per-episode scalars (one row per episode, in one batch)."""
        if not self._pending:
            return
        self.rec.reset_time()
        log_episode_scalars(self.rr, self.rec, self._pending, styles=not self._styled)
        self._styled = True
        self._pending = []

    # -- clusters --------------------------------------------------------------------------
    def on_cluster_model(self, msg: pb.ClusterModel) -> bool:
        """A newer model: centroids and recoloured failed goals at the episode after the last
        one seen (from then on the replay labels episodes with it); one that comes before any
        header (a live view joining a running run) is drawn at the first header. False if not
        newer (a late joiner may get an older model still in flight)."""
        validate_centroids(msg, k=self.k, goal_dim=self.spec.goal_dim)
        if int(msg.version) <= self._model_version:
            return False
        model = msg_to_cluster_model(msg)
        self._model_version = model.version
        self._centroids = model.centroids
        if self._last_episode < 0:
            self._early_model = model
        else:
            self._log_model(model, at_episode=self._last_episode + 1)
        return True

    def _log_model(self, model: ClusterModel, *, at_episode: int) -> None:
        self.rec.reset_time()
        log_centroids(self.rr, self.rec, LoggedModel(at_episode=at_episode, model=model))
        self._log_failed_goals(at_episode)
        self.models += 1

    def _log_failed_goals(self, at_episode: int) -> None:
        goals = (np.stack(self._failed) if self._failed
                 else np.zeros((0, self.spec.goal_dim), np.float32))
        log_failed_goals(self.rr, self.rec, at_episode=at_episode, goals=goals,
                         centroids=self._centroids)
        self.rec.reset_time()

    # -- curves ----------------------------------------------------------------------------
    def on_status(self, msg: pb.ReplayStatus) -> None:
        self._cluster_sizes = [float(c) for c in msg.cluster_sizes]

    def on_metrics(self, msg: pb.Metrics) -> bool:
        """The learner's row of an epoch → `curves/<name>`; False for other services' metrics
        and epochs already logged."""
        values = dict(msg.values)
        if not msg.service.startswith("learner/") or "epoch" not in values:
            return False
        epoch = int(values["epoch"])
        if epoch <= self._last_epoch:
            return False
        self._last_epoch = epoch
        rec, rr = self.rec, self.rr
        rec.reset_time()
        rec.set_time("epoch", sequence=epoch)
        episodes = values.get("episodes")
        if episodes is not None and math.isfinite(episodes) and episodes >= 1:
            rec.set_time("episode", sequence=int(episodes) - 1)
        for name in sorted(values):
            value = values[name]
            if name in _NOT_CURVES or not math.isfinite(value):
                continue
            if name not in self._curves:
                declare_curve(rr, rec, name)
                self._curves.add(name)
            rec.log(f"curves/{name}", rr.Scalars(value))
        if self._cluster_sizes:
            rec.log("curves/cluster_sizes", rr.Scalars(np.asarray(self._cluster_sizes)))
        rec.reset_time()
        self.epochs += 1
        return True
