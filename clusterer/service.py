"""The clusterer process (`hercs clusterer`): a thin Zenoh shell around `clusterer.core`.

What `run` does:
- subscribes to `keys.inserted` (one `EpisodeHeader` per stored episode). The subscription
  thread only parses and checks each header (schema, finite goal_dim-vectors) and appends
  (ag_T, g) to an inbox; a bad header is counted by reason, logged once per reason per minute
  and skipped. Refits (k-means, tens of ms or more) run on the main loop, never on the
  subscription thread, so Zenoh's receive path is never held up.
- the main loop feeds each pair to `Clusterer.observe`; when it returns a new model, that
  model is published as `ClusterModel(version, centroids, fitted_on, failed_goals_seen)` on
  `keys.cluster_model` with `latest=True`, so a replay that joins (or restarts) later gets it
  at once.
- methods without clusters (`her`, `her-ebp`): the process runs the same way (the topology is
  uniform) and counts episodes and failures for its metrics, but never fits nor publishes a
  model: nobody would use it, and skipping k-means keeps a core free.
- metrics (episodes seen, failed goals seen, refits, model version, rejects) about once per
  `METRICS_PERIOD_S` while headers arrive, and after each refit.
- SIGTERM/SIGINT: the loop ends within `_POLL_S`, the transport closes, exit 0. The failed-goal
  buffer is not persisted: a restarted clusterer starts a fresh buffer and counts versions from
  1 again.
"""

from __future__ import annotations

import logging
import queue
import threading
import time

import numpy as np

from clusterer.core import Clusterer
from hercs.clustering import ClusterModel
from hercs.codec import array_to_msg
from hercs.config import HercsConfig
from hercs.errors import InvalidMessage
from hercs.service import ServiceRuntime, WarnOncePerMinute, service_main
from hercs.transport import TransportError
from hercs.validation import header_goals, parse_message
from proto import SCHEMA_VERSION
from proto import hercs_pb2 as pb

log = logging.getLogger(__name__)

METRICS_PERIOD_S = 1.0
_POLL_S = 0.25
_HEADER_MAX_BYTES = 64 * 1024


def decode_header(raw: bytes, *, goal_dim: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """`EpisodeHeader` bytes → (final achieved goal, desired goal), float64 (goal_dim,) each.

    Raises `InvalidMessage` (a `RejectReason`) for undecodable bytes, a wrong schema version,
    a missing or misshapen vector, or NaN/Inf.
    """
    msg = parse_message(raw, pb.EpisodeHeader, max_bytes=_HEADER_MAX_BYTES)
    return header_goals(msg, goal_dim=goal_dim)


def model_to_msg(model: ClusterModel, *, failed_goals_seen: int) -> pb.ClusterModel:
    return pb.ClusterModel(
        schema_version=SCHEMA_VERSION,
        version=model.version,
        centroids=array_to_msg(model.centroids),
        fitted_on=model.n_goals,
        failed_goals_seen=failed_goals_seen,
    )


class ClustererService:
    """The clusterer's loop; `run()` returns when `runtime.stop` is set."""

    def __init__(self, *, runtime: ServiceRuntime, config: HercsConfig) -> None:
        self.runtime = runtime
        self.config = config
        self.goal_dim = config.task.spec.goal_dim
        self.fits = config.run.uses_clusters
        self.core = Clusterer(config=config.cluster, seed=config.run.seed,
                              spec=config.task.spec)
        self.episodes_seen = 0
        self.failures_seen = 0
        self.refits = 0
        self.rejected: dict[str, int] = {}
        """Headers skipped, by reason (written by the subscription thread)."""
        self._rejected_lock = threading.Lock()
        self._warn = WarnOncePerMinute(log)
        self._inbox: queue.SimpleQueue[tuple[np.ndarray, np.ndarray]] = queue.SimpleQueue()
        keys, transport = runtime.keys, runtime.transport
        self._models = (transport.publisher(keys.cluster_model, latest=True, block=True)
                        if self.fits else None)
        transport.subscribe(keys.inserted, self._on_header, capacity=1024)

    def _on_header(self, key: str, raw: bytes) -> None:
        """Subscription thread: check and hand over; never fits (SimpleQueue.put never blocks)."""
        try:
            pair = decode_header(raw, goal_dim=self.goal_dim)
        except InvalidMessage as exc:
            with self._rejected_lock:
                self.rejected[exc.reason] = self.rejected.get(exc.reason, 0) + 1
            self._warn.warn(f"header:{exc.reason}",
                            f"skipped an EpisodeHeader on {key}: {exc}")
            return
        self._inbox.put(pair)

    def observe(self, final_ag: np.ndarray, desired_goal: np.ndarray) -> ClusterModel | None:
        """One stored episode; the new model if it triggered a refit (cluster methods only)."""
        self.episodes_seen += 1
        if not self.fits:
            self.failures_seen += int(not self.config.task.spec.is_success(final_ag,
                                                                            desired_goal))
            return None
        model = self.core.observe(final_ag=final_ag, desired_goal=desired_goal)
        self.failures_seen = self.core.failures_seen
        return model

    def run(self) -> int:
        stop = self.runtime.stop
        log.info("clusterer %s: run %r, method %s (%s), fgb %d, k %d", self.runtime.ident,
                 self.config.run.name, self.config.run.method,
                 "fitting" if self.fits else "counting only", self.config.cluster.fgb_size,
                 self.config.cluster.k)
        self.publish_metrics()
        next_metrics = time.monotonic() + METRICS_PERIOD_S
        dirty = False
        while not stop.is_set():
            try:
                final_ag, desired_goal = self._inbox.get(timeout=_POLL_S)
            except queue.Empty:
                model = None
            else:
                dirty = True
                model = self.observe(final_ag, desired_goal)
            if model is not None and self._models is not None:
                self.refits += 1
                self._models.put(model_to_msg(model, failed_goals_seen=self.failures_seen)
                                 .SerializeToString())
                log.info("cluster model version %d fitted on %d failed goals (%d seen)",
                         model.version, model.n_goals, self.failures_seen)
            now = time.monotonic()
            if model is not None or (dirty and now >= next_metrics):
                self.publish_metrics()
                next_metrics, dirty = now + METRICS_PERIOD_S, False
        self.publish_metrics()
        return 0

    def publish_metrics(self) -> None:
        model = self.core.model
        with self._rejected_lock:
            rejected = dict(self.rejected)
        values = {
            "episodes_seen": self.episodes_seen,
            "failed_goals_seen": self.failures_seen,
            "refits": self.refits,
            "model_version": 0 if model is None else model.version,
            "rejected": sum(rejected.values()),
            "inbox": self._inbox.qsize(),
        }
        values.update({f"rejected_{reason}": n for reason, n in rejected.items()})
        try:
            self.runtime.publish_metrics(values)
        except TransportError as exc:  # metrics are best effort
            self._warn.warn("metrics", f"could not publish metrics: {exc}")


def run(config: HercsConfig, *, ident: str | None = None) -> int:
    """`hercs clusterer`: cluster the run's failed goals until SIGTERM/SIGINT."""
    return service_main(role="clusterer", config=config, ident=ident,
                        body=lambda runtime: ClustererService(runtime=runtime,
                                                              config=runtime.config).run())
