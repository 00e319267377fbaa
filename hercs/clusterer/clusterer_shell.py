"""The clusterer process (`hercs clusterer`): a thin Zenoh shell around its core.

The subscription thread only checks `EpisodeHeader`s and queues (ag_T, g); `Clusterer.observe`
and the k-means refits (tens of ms or more) run on the main loop, so Zenoh's receive path is
never held up. A bad header is counted by reason, logged once per minute and skipped. Models
go out on `keys.cluster_model` with `latest=True`, so a replay that starts later gets one at
once. For `her` and `her-ebp` the process runs all the same (the topology is uniform) but only
counts: no one would use a model. On start it continues from the replay's
`replay/clusterer_state` (buffer, counts, model numbering), skipping headers already in it.
"""

from __future__ import annotations

import logging
import queue
import threading
import time

import numpy as np

from hercs.clusterer.builder import ClustererBuilder
from hercs.config import HercsConfig
from hercs.errors import InvalidMessage
from hercs.net.backoff import Backoff
from hercs.net.service_shell import ServiceRuntime, service_main
from hercs.net.transport import TransportError
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.rl.cluster_model import ClusterModel
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.codec import cluster_model_to_msg, msg_to_array
from hercs.wire.validation import header_goals, parse_message

log = logging.getLogger(__name__)

METRICS_PERIOD_S = 1.0
_POLL_S = 0.25
STATE_TIMEOUT_S = 10.0
_HEADER_MAX_BYTES = 64 * 1024


def decode_header(raw: bytes, *, goal_dim: int = 3) -> tuple[int, np.ndarray, np.ndarray]:
    """`EpisodeHeader` bytes → (episode id, final achieved goal, desired goal), the goals
    float64 (goal_dim,) each.

    Raises `InvalidMessage` (a `hercs.reasons.Reason`) for undecodable bytes, a wrong schema
    version, a missing or misshapen vector, or NaN/Inf.
    """
    msg = parse_message(raw, pb.EpisodeHeader, max_bytes=_HEADER_MAX_BYTES)
    return (int(msg.episode_id), *header_goals(msg, goal_dim=goal_dim))


class ClustererService:
    """The clusterer's loop; `run()` returns when `runtime.stop` is set."""

    def __init__(self, *, parts: ClustererBuilder, runtime: ServiceRuntime) -> None:
        self.runtime = runtime
        self.settings = settings = parts.shell
        self.goal_dim = settings.spec.goal_dim
        self.fits = settings.fits
        self.core = parts.core()
        self.episodes_seen = 0
        self.failures_seen = 0
        self.refits = 0
        self.rejected: dict[str, int] = {}
        """Headers skipped, by reason (written by the subscription thread)."""
        self._rejected_lock = threading.Lock()
        self._warn = WarnOncePerMinute(log)
        self._inbox: queue.SimpleQueue[tuple[int, np.ndarray, np.ndarray]] = queue.SimpleQueue()
        self._counted_below = 0
        """Episode ids below this are in the replay's snapshot (`resume_from_replay`)."""
        keys, transport = runtime.keys, runtime.transport
        self._models = (transport.publisher(keys.cluster_model, latest=True, block=True)
                        if self.fits else None)
        transport.subscribe(keys.inserted, self._on_header, capacity=1024)

    def _on_header(self, key: str, raw: bytes) -> None:
        """Subscription thread: check and hand over; never fits (SimpleQueue.put never blocks)."""
        try:
            item = decode_header(raw, goal_dim=self.goal_dim)
        except InvalidMessage as exc:
            with self._rejected_lock:
                self.rejected[exc.reason] = self.rejected.get(exc.reason, 0) + 1
            self._warn.warn(f"header:{exc.reason}",
                            f"skipped an EpisodeHeader on {key}: {exc}")
            return
        self._inbox.put(item)

    def observe(self, final_ag: np.ndarray, desired_goal: np.ndarray) -> ClusterModel | None:
        """One stored episode; the new model if it triggered a refit (cluster methods only)."""
        self.episodes_seen += 1
        if not self.fits:
            self.failures_seen += int(not self.settings.spec.is_success(final_ag,
                                                                         desired_goal))
            return None
        model = self.core.observe(final_ag=final_ag, desired_goal=desired_goal)
        self.failures_seen = self.core.failures_seen
        return model

    def run(self) -> int:
        stop = self.runtime.stop
        settings = self.settings
        log.info("clusterer %s: run %r, method %s (%s), fgb %d, k %d", self.runtime.ident,
                 settings.run, settings.method, "fitting" if self.fits else "counting only",
                 settings.fgb_size, settings.clusters)
        if not self.resume_from_replay():
            return 0  # stopped while the replay was away
        self.publish_metrics()
        next_metrics = time.monotonic() + METRICS_PERIOD_S
        dirty = False
        while not stop.is_set():
            try:
                episode_id, final_ag, desired_goal = self._inbox.get(timeout=_POLL_S)
            except queue.Empty:
                model = None
            else:
                if episode_id < self._counted_below:
                    continue  # in the replay's snapshot already
                dirty = True
                model = self.observe(final_ag, desired_goal)
            if model is not None and self._models is not None:
                self.refits += 1
                self._models.put(cluster_model_to_msg(model).SerializeToString())
                log.info("cluster model version %d fitted on %d failed goals (%d seen)",
                         model.version, model.n_goals, model.failures_seen)
            now = time.monotonic()
            if model is not None or (dirty and now >= next_metrics):
                self.publish_metrics()
                next_metrics, dirty = now + METRICS_PERIOD_S, False
        self.publish_metrics()
        return 0

    def resume_from_replay(self) -> bool:
        """Continue the run where it stands: ask the replay (retrying while it is away) for
        the newest failed goals, the counts and the version of its cluster model. A fresh run
        gets an empty snapshot. False if stopped first."""
        stop, keys = self.runtime.stop, self.runtime.keys
        request = pb.ClustererStateRequest(schema_version=SCHEMA_VERSION).SerializeToString()
        backoff = Backoff(0.2, 2.0)
        while not stop.is_set():
            try:
                raw = self.runtime.transport.request(keys.clusterer_state, request,
                                                     timeout_s=STATE_TIMEOUT_S)
                state = parse_message(raw, pb.ClustererState, max_bytes=1 << 20)
                goals = msg_to_array(state.failed_goals, where="ClustererState.failed_goals")
                if goals.ndim != 2 or goals.shape[1] != self.goal_dim or len(goals) > \
                        self.settings.fgb_size or not np.isfinite(goals).all():
                    raise InvalidMessage(Reason.BAD_SHAPE,
                                         f"ClustererState.failed_goals: shape {goals.shape} "
                                         "or values unusable")
            except (TransportError, InvalidMessage) as exc:
                self._warn.warn("state", f"waiting for the replay's clusterer state: {exc}")
                backoff.wait(stop)
                continue
            self.core.resume(failed_goals=goals, failures_seen=int(state.failures_seen),
                             episodes_seen=int(state.episodes_seen),
                             model_version=int(state.model_version))
            self._counted_below = int(state.episodes_seen)
            self.episodes_seen, self.failures_seen = (int(state.episodes_seen),
                                                      int(state.failures_seen))
            if state.episodes_seen:
                log.info("continuing run %r: %d failed goals of %d episodes, next model "
                         "version %d", self.settings.run, state.failures_seen,
                         state.episodes_seen, state.model_version + 1)
            return True
        return False

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
                        body=lambda runtime: ClustererService(
                            parts=ClustererBuilder(runtime.config), runtime=runtime).run())
