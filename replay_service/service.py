"""`hercs replay`: the replay service process, a thin shell around `ReplayCore`.

Queries (served on our own worker threads, never inside Zenoh callbacks):
- `replay/insert` (Episode → InsertAck): decoded and validated; a retry of a stored
  (actor_id, seq) is acked at once as a duplicate; otherwise, when the rate limiter admits it,
  the episode is appended durably to the MCAP log, stored, acked, and its `EpisodeHeader` put
  on `replay/inserted`. When the limiter holds inserts the query is parked and answered later.
- `replay/sample` (SampleRequest → Batch): parked until the limiter admits it.
- `config`: the run's resolved config as YAML (remote actors start from it).
- `replay/episode` (EpisodeRequest → Episode): one stored episode by id, as inserted (the live
  view draws every n-th episode's trajectory from it). An id never inserted or already
  overwritten by the ring gets the error reply `unknown_episode` (a miss, not counted as a
  reject); a malformed request is a reject like any other.
Subscriptions: `cluster/model` (latest, so a restarted replay gets the current model at once)
and `eval/result` (logged). `replay/status` is put about once a second.

All state changes happen under one lock; after each insert or sample the parked queries of
the other side are retried, oldest first (FIFO per side).

On start the episode log of the run directory is replayed into the core, so nothing acked is
lost across a restart; the rate limiter restarts balanced at the recovered size.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from hercs.clustering import ClusterModel
from hercs.codec import (
    array_to_msg,
    episode_to_msg,
    minibatch_to_msg,
    msg_to_array,
    msg_to_episode,
    stats_to_msg,
)
from hercs.config import HercsConfig, save_yaml
from hercs.episode import EpisodeData
from hercs.errors import InvalidMessage
from hercs.runlog.episode_log import EpisodeLog
from hercs.seeding import generator
from hercs.service import ServiceRuntime, WarnOncePerMinute, setup_logging
from hercs.transport import PendingReply
from hercs.validation import (
    RejectReason,
    parse_message,
    validate_centroids,
    validate_episode,
    validate_sample_request,
)
from proto import SCHEMA_VERSION
from proto import hercs_pb2 as pb
from replay_service.core import ReplayCore
from replay_service.rate_limiter import SampleToInsertRatio

log = logging.getLogger("hercs.replay")

STATUS_PERIOD_S = 1.0
MAX_MINIBATCHES_PER_REQUEST = 400
MAX_BATCH_SIZE = 8192
POLICY_LAG_WINDOW = 64
"""Recent episodes whose policy lag is averaged into each Batch's `policy_lag`."""


@dataclass
class _ParkedInsert:
    pending: PendingReply
    msg: pb.Episode
    episode: EpisodeData


@dataclass
class _ParkedSample:
    pending: PendingReply
    request: pb.SampleRequest


class ReplayService:
    """The replay's process-side state: core, limiter, log and parked queries."""

    def __init__(self, *, config: HercsConfig, runtime: ServiceRuntime, run_dir: Path) -> None:
        self.config = config
        self.runtime = runtime
        self.spec = config.task.spec
        self.core = ReplayCore(config=config, rng=generator(config.run.seed, "replay"))
        self.limiter = SampleToInsertRatio(
            samples_per_insert=config.training.updates_per_episode,
            min_size_to_sample=config.replay.min_episodes_to_sample,
            error_buffer=config.replay.rate_tolerance_updates,
            max_request=config.training.minibatches_per_cycle,
            free_run=config.replay.free_run,
        )
        self.lock = threading.Lock()
        self.parked_inserts: deque[_ParkedInsert] = deque()
        self.parked_samples: deque[_ParkedSample] = deque()
        # Policy lag of an episode = the learner's newest weights version when the episode
        # arrives (known from its latest SampleRequest) minus the version the actor used.
        self.learner_version = 0
        self.recent_lags: deque[int] = deque(maxlen=POLICY_LAG_WINDOW)
        self.warn = WarnOncePerMinute(log)
        self.log, recovered = EpisodeLog.open(run_dir, run=config.run.name,
                                              task=self.spec.name)
        self._recover(recovered)
        self._config_yaml = yaml.safe_dump(config.to_dict(), sort_keys=False).encode()

        keys, transport = runtime.keys, runtime.transport
        self.inserted_pub = transport.publisher(keys.inserted, block=True)
        self.status_pub = transport.publisher(keys.status)
        transport.serve(keys.config, lambda _: self._config_yaml)
        transport.serve(keys.episode, self._on_episode_request,
                        on_error=self._on_episode_request_error)
        transport.subscribe(keys.cluster_model, self._on_cluster_model, latest=True)
        transport.subscribe(keys.eval_result, self._on_eval_result)
        transport.serve_deferred(keys.insert, self._on_insert, on_error=self._on_reject)
        transport.serve_deferred(keys.sample, self._on_sample, on_error=self._on_reject)

    # -- start-up --------------------------------------------------------------------------
    def _recover(self, recovered) -> None:
        count = 0
        for episode_id, msg in recovered:
            result = self.core.insert(msg_to_episode(msg))
            if result.episode_id != episode_id:
                log.warning("recovered episode logged as id %d was stored as %d", episode_id,
                            result.episode_id)
            count += 1
        if count:
            # Restart balanced: as if the learner had used every recovered episode.
            self.limiter.inserts = count
            self.limiter.samples = int(count * self.limiter.samples_per_insert)
            log.info("recovered %d acked episodes from the episode log", count)

    # -- inserts ---------------------------------------------------------------------------
    def _on_reject(self, exc: Exception) -> None:
        reason = exc.reason if isinstance(exc, InvalidMessage) else "internal"
        with self.lock:
            self.core.count_reject(reason)
        self.warn.warn(f"reject:{reason}", f"rejected a message: {exc}")

    def _on_insert(self, pending: PendingReply) -> None:
        msg = parse_message(pending.payload, pb.Episode,
                            max_bytes=self.config.replay.max_message_bytes)
        rejection = validate_episode(msg, self.spec, run=self.config.run.name)
        if rejection is not None:
            raise rejection.error()
        episode = msg_to_episode(msg)
        with self.lock:
            known = self.core.lookup(episode.actor_id, episode.seq)
            if known is not None:
                self.core.duplicates += 1
                pending.reply(self._ack(episode, known, duplicate=True))
                return
            self.parked_inserts.append(_ParkedInsert(pending, msg, episode))
            self._drain()

    def _store(self, item: _ParkedInsert) -> None:
        """Log durably, store, ack, announce. Caller holds the lock."""
        episode = item.episode
        known = self.core.lookup(episode.actor_id, episode.seq)
        if known is not None:  # a retry parked beside its first attempt
            self.core.duplicates += 1
            item.pending.reply(self._ack(episode, known, duplicate=True))
            return
        episode_id = self.core.store.num_inserted
        self.log.append_episode(item.msg, episode_id=episode_id)
        result = self.core.insert(episode)
        assert result.episode_id == episode_id, "log and store disagree on episode ids"
        self.limiter.record_insert()
        self.recent_lags.append(self.learner_version - episode.policy_version)
        item.pending.reply(self._ack(episode, episode_id, duplicate=False))
        header = pb.EpisodeHeader(
            schema_version=SCHEMA_VERSION, episode_id=episode_id, actor_id=episode.actor_id,
            seq=episode.seq, success=episode.success,
            final_achieved_goal=array_to_msg(episode.ag[-1]),
            desired_goal=array_to_msg(episode.g[-1]), energy=result.energy,
            cluster=result.cluster, policy_version=episode.policy_version,
        )
        self.inserted_pub.put(header.SerializeToString())

    @staticmethod
    def _ack(episode: EpisodeData, episode_id: int, *, duplicate: bool) -> bytes:
        return pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id=episode.actor_id,
                            seq=episode.seq, episode_id=episode_id,
                            duplicate=duplicate).SerializeToString()

    # -- stored episodes (the live view) ---------------------------------------------------
    def _on_episode_request(self, payload: bytes) -> bytes:
        request = parse_message(payload, pb.EpisodeRequest,
                                max_bytes=self.config.replay.max_message_bytes)
        episode_id = int(request.episode_id)
        with self.lock:
            store = self.core.store
            episode = store.episode(episode_id)
            first, end = store.num_inserted - store.size, store.num_inserted
        if episode is None:
            why = "not inserted yet" if episode_id >= end else "overwritten by newer episodes"
            held = f"ids {first}..{end - 1}" if end > first else "no episode yet"
            raise InvalidMessage(
                RejectReason.UNKNOWN_EPISODE,
                f"EpisodeRequest.episode_id {episode_id}: not stored ({why}; the replay holds "
                f"{held})")
        return episode_to_msg(episode, run=self.config.run.name,
                              task=self.spec.name).SerializeToString()

    def _on_episode_request_error(self, exc: Exception) -> None:
        if isinstance(exc, InvalidMessage) and exc.reason == RejectReason.UNKNOWN_EPISODE:
            log.debug("episode request: %s", exc)
            return
        self._on_reject(exc)

    # -- samples ---------------------------------------------------------------------------
    def _on_sample(self, pending: PendingReply) -> None:
        request = parse_message(pending.payload, pb.SampleRequest,
                                max_bytes=self.config.replay.max_message_bytes)
        rejection = validate_sample_request(
            request, run=self.config.run.name, max_minibatches=MAX_MINIBATCHES_PER_REQUEST,
            max_batch_size=MAX_BATCH_SIZE)
        if rejection is not None:
            raise rejection.error()
        with self.lock:
            self.parked_samples.append(_ParkedSample(pending, request))
            self._drain()

    def _serve_sample(self, item: _ParkedSample) -> None:
        request = item.request
        self.learner_version = max(self.learner_version, int(request.weights_version))
        result = self.core.sample(int(request.num_minibatches), int(request.batch_size))
        self.limiter.record_sample(int(request.num_minibatches))
        o_state, g_state = self.core.normalizer_state()
        model = self.core.cluster_model
        lag = float(np.mean(self.recent_lags)) if self.recent_lags else 0.0
        batch = pb.Batch(
            schema_version=SCHEMA_VERSION, request_id=request.request_id,
            minibatches=[minibatch_to_msg(mb) for mb in result.minibatches],
            o_stats=stats_to_msg(o_state), g_stats=stats_to_msg(g_state),
            cluster_model_version=0 if model is None else model.version,
            cluster_draws=[int(c) for c in result.cluster_draws],
            inserts=self.core.inserts, env_steps=self.core.env_steps, policy_lag=lag,
        )
        item.pending.reply(batch.SerializeToString())

    # -- the rate limiter's queue ----------------------------------------------------------
    def _drain(self) -> None:
        """Serve parked queries, oldest first per side, while the limiter admits them.

        Caller holds the lock. Alternating sides until neither can move keeps the order fair;
        it terminates because each step consumes one parked query.
        """
        progressed = True
        while progressed:
            progressed = False
            while self.parked_inserts and self.limiter.can_insert():
                self._store(self.parked_inserts.popleft())
                progressed = True
            while self.parked_samples and self.limiter.can_sample(
                    int(self.parked_samples[0].request.num_minibatches)):
                self._serve_sample(self.parked_samples.popleft())
                progressed = True

    # -- cluster model and eval results ----------------------------------------------------
    def _on_cluster_model(self, key: str, payload: bytes) -> None:
        try:
            msg = parse_message(payload, pb.ClusterModel,
                                max_bytes=self.config.replay.max_message_bytes)
            rejection = validate_centroids(msg, k=self.config.cluster.k,
                                           goal_dim=self.spec.goal_dim)
            if rejection is not None:
                raise rejection.error()
            model = ClusterModel(version=int(msg.version),
                                 centroids=msg_to_array(msg.centroids).copy(),
                                 n_goals=int(msg.fitted_on),
                                 inserts_seen=int(msg.failed_goals_seen))
        except (InvalidMessage, ValueError) as exc:
            reason = exc.reason if isinstance(exc, InvalidMessage) else RejectReason.BAD_VALUE
            self._on_reject(InvalidMessage(str(reason), f"ClusterModel: {exc}"))
            return
        with self.lock:
            if self.core.set_cluster_model(model):
                self.log.append_cluster_model(msg)
                log.info("cluster model v%d adopted; cluster sizes %s", model.version,
                         self.core.cluster_sizes().tolist())

    def _on_eval_result(self, key: str, payload: bytes) -> None:
        try:
            msg = parse_message(payload, pb.EvalResult,
                                max_bytes=self.config.replay.max_message_bytes)
        except InvalidMessage as exc:
            self._on_reject(exc)
            return
        with self.lock:
            self.log.append_eval_result(msg)

    # -- status ----------------------------------------------------------------------------
    def status(self) -> pb.ReplayStatus:
        with self.lock:
            core = self.core
            model = core.cluster_model
            return pb.ReplayStatus(
                schema_version=SCHEMA_VERSION, size_episodes=core.store.size,
                size_transitions=core.store.num_transitions, inserts=core.inserts,
                duplicates=core.duplicates, samples=core.samples,
                rate_limiter=self.limiter.describe(inserts_waiting=len(self.parked_inserts),
                                                   samples_waiting=len(self.parked_samples)),
                rejects=dict(core.rejects),
                cluster_sizes=[int(c) for c in core.cluster_sizes()],
                cluster_model_version=0 if model is None else model.version,
            )

    def close(self) -> None:
        with self.lock:
            self.log.close()


def run(config: HercsConfig, *, ident: str | None = None) -> int:
    setup_logging("replay")
    run_dir = Path(config.run.run_dir) / config.run.name
    run_dir.mkdir(parents=True, exist_ok=True)
    if not (run_dir / "config.yaml").exists():  # `hercs up` writes it; compose runs do not
        save_yaml(config, run_dir / "config.yaml")
    with ServiceRuntime(config=config, role="replay", ident=ident or "replay") as runtime:
        service = ReplayService(config=config, runtime=runtime, run_dir=run_dir)
        log.info("replay serving run %s (%s, %s), capacity %d episodes", config.run.name,
                 config.task.name, config.run.method, config.capacity_episodes)
        try:
            while not runtime.stop.wait(STATUS_PERIOD_S):
                service.status_pub.put(service.status().SerializeToString())
        finally:
            runtime.transport.close()  # answers parked queries `unavailable` first
            service.close()
    return 0
