"""`hercs replay`: the replay service process, a thin Zenoh shell around `ReplayTable`.

It decodes and validates each query and hands it to the table with a waiter that answers it,
now or later; every decision is the table's. Queries are served on our own worker threads,
never inside Zenoh callbacks. On start the episode log is replayed into the table, so nothing
acked is lost across a restart (docs/DESIGN.md §6, §8).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Generic, TypeVar

import yaml

from hercs.config import HercsConfig, load_yaml, save_yaml
from hercs.errors import ConfigError, InvalidMessage
from hercs.net.service_shell import ServiceRuntime, service_main
from hercs.net.transport import PendingReply
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.replay_core import ReplayCore
from hercs.replay_service.table import ReplayTable, SampleCall, SampleRefused, Stored
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.seeding import generator
from hercs.run.rundir import RunDir, run_dir_of
from hercs.run.runlog import (
    MAX_SEQUENCE,
    EpisodeLogError,
    RecoveringLogWriter,
    read_cluster_models,
)
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.codec import (
    array_to_msg,
    episode_to_msg,
    msg_to_cluster_model,
    msg_to_episode,
    msg_to_replay_state,
)
from hercs.wire.served import counters_to_msg, served_batch_to_bytes
from hercs.wire.validation import (
    decode_episode,
    parse_message,
    validate_centroids,
    validate_eval_result,
    validate_sample_request,
)

log = logging.getLogger("hercs.replay")

STATUS_PERIOD_S = 1.0
MAX_MINIBATCHES_PER_REQUEST = 400
MAX_BATCH_SIZE = 8192
MAX_ROWS_PER_REQUEST = 1 << 18
"""Transitions in one Batch reply: 262,144 rows, ~61 MB for the object tasks (the learner asks
for 40 × 256 = 10,240). Without it one valid request could make the replay build GBs."""

R = TypeVar("R")


@dataclass
class _QueryWaiter(Generic[R]):
    """Answers one deferred Zenoh query for the table."""

    pending: PendingReply
    encode: Callable[[R], bytes]

    def done(self, result: R) -> None:
        self.pending.reply(self.encode(result))

    def fail(self, reason: Reason, detail: str) -> None:
        self.pending.reply_error(reason, detail)


class ReplayService:
    """The replay's process side: decode, call the table, encode, reply."""

    def __init__(self, *, config: HercsConfig, runtime: ServiceRuntime, run_dir: Path) -> None:
        self.config = config
        self.runtime = runtime
        self.spec = config.task.spec
        self.warn = WarnOncePerMinute(log)
        replay = config.replay
        self.log, recovered = RecoveringLogWriter.open(
            run_dir, run=config.run.name, task=self.spec.name, scene=replay.log_scene,
            segment_episodes=replay.log_segment_episodes(config.capacity_episodes),
            max_bytes=replay.log_max_bytes, spec=self.spec)
        saved = recovered.replay_state
        self.table = ReplayTable(
            config=config, core=ReplayCore(config=config, rng=generator(config.run.seed,
                                                                       "replay")),
            log=self.log)
        count = 0

        def episodes():
            nonlocal count
            for episode_id, msg in recovered:
                count += 1
                yield episode_id, msg_to_episode(msg)

        state = None if saved is None else msg_to_replay_state(saved)
        for logged, stored in self.table.recover(episodes(), state=state):
            log.warning("recovered episode logged as id %d was stored as %d", logged, stored)
        if state is not None:
            log.info("started from the replay state the episode log saved at episode %d "
                     "(its buffer's oldest episode: %d)", state.next_episode_id,
                     state.first_held_id)
        if count:
            log.info("recovered %d acked episodes from the episode log", count)
            self._restore_cluster_model(run_dir, saved)
        self._config_yaml = yaml.safe_dump(config.to_dict(), sort_keys=False).encode()

        keys, transport = runtime.keys, runtime.transport
        self.inserted_pub = transport.publisher(keys.inserted, block=True)
        self.status_pub = transport.publisher(keys.status)
        transport.serve(keys.config, lambda _: self._config_yaml)
        transport.serve(keys.episode, self._on_episode_request,
                        on_error=self._on_episode_request_error)
        transport.serve(keys.clusterer_state, self._on_clusterer_state, on_error=self._on_reject)
        transport.subscribe(keys.cluster_model, self._on_cluster_model, latest=True)
        transport.subscribe(keys.eval_result, self._on_eval_result)
        transport.serve_deferred(keys.insert, self._on_insert, on_error=self._on_reject,
                                 workers=config.replay.insert_workers)
        transport.serve_deferred(keys.sample, self._on_sample, on_error=self._on_reject)

    def _restore_cluster_model(self, run_dir: Path, saved: pb.ReplayState | None) -> None:
        """The newest cluster model of the log (logged, or held by its saved replay state),
        so that a restarted replay samples by clusters at once even if no clusterer
        republishes its model."""
        models = list(read_cluster_models(run_dir))
        if saved is not None and saved.HasField("cluster_model"):
            models.append(saved.cluster_model)
        if not models:
            return
        last = max(models, key=lambda m: m.version)
        try:
            model = self._cluster_model(last)
        except InvalidMessage as exc:
            log.warning("the log's last cluster model is not usable (%s); waiting for one", exc)
            return
        if self.table.adopt_cluster_model(model, None):
            log.info("cluster model v%d restored from the episode log", model.version)

    # -- inserts ---------------------------------------------------------------------------
    def _on_reject(self, exc: Exception) -> None:
        reason = exc.reason if isinstance(exc, InvalidMessage) else Reason.INTERNAL
        self.table.count_reject(reason)
        self.warn.warn(f"reject:{reason}", f"rejected a message: {exc}")

    def _on_insert(self, pending: PendingReply) -> None:
        msg, episode = decode_episode(pending.payload, self.spec, run=self.config.run.name,
                                      max_bytes=self.config.replay.max_message_bytes)
        self.table.insert(episode, record=msg,
                          waiter=_QueryWaiter(pending, self._acked),
                          timeout_s=self.config.actor.insert_timeout_s)

    def _acked(self, stored: Stored) -> bytes:
        """The ack's bytes; a newly stored episode is also announced on `replay/inserted`."""
        episode = stored.episode
        if not stored.duplicate:
            header = pb.EpisodeHeader(
                schema_version=SCHEMA_VERSION, episode_id=stored.episode_id,
                actor_id=episode.actor_id, seq=episode.seq, success=episode.success,
                final_achieved_goal=array_to_msg(episode.ag[-1]),
                desired_goal=array_to_msg(episode.g[-1]), energy=stored.energy,
                cluster=stored.cluster, policy_version=episode.policy_version,
            )
            self.inserted_pub.put(header.SerializeToString())
        return pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id=episode.actor_id,
                            seq=episode.seq, episode_id=stored.episode_id,
                            duplicate=stored.duplicate,
                            next_policy_version=stored.next_policy_version).SerializeToString()

    # -- stored episodes (the live view) ---------------------------------------------------
    def _on_episode_request(self, payload: bytes) -> bytes:
        request = parse_message(payload, pb.EpisodeRequest,
                                max_bytes=self.config.replay.max_message_bytes)
        episode_id = int(request.episode_id)
        episode, first, end = self.table.stored_episode(episode_id)
        if episode is None:
            why = "not inserted yet" if episode_id >= end else "overwritten by newer episodes"
            held = (f"{end - first} episodes with ids up to {end - 1}" if end > first
                    else "no episode yet")
            raise InvalidMessage(
                Reason.UNKNOWN_EPISODE,
                f"EpisodeRequest.episode_id {episode_id}: not stored ({why}; the replay holds "
                f"{held})")
        return episode_to_msg(episode, run=self.config.run.name,
                              task=self.spec.name).SerializeToString()

    def _on_episode_request_error(self, exc: Exception) -> None:
        if isinstance(exc, InvalidMessage) and exc.reason == Reason.UNKNOWN_EPISODE:
            log.debug("episode request: %s", exc)
            return
        self._on_reject(exc)

    # -- samples ---------------------------------------------------------------------------
    def _on_sample(self, pending: PendingReply) -> None:
        request = parse_message(pending.payload, pb.SampleRequest,
                                max_bytes=self.config.replay.max_message_bytes)
        validate_sample_request(
            request, run=self.config.run.name, max_minibatches=MAX_MINIBATCHES_PER_REQUEST,
            max_batch_size=MAX_BATCH_SIZE, max_rows=MAX_ROWS_PER_REQUEST)
        call = SampleCall(num_minibatches=int(request.num_minibatches),
                          batch_size=int(request.batch_size),
                          weights_version=int(request.weights_version),
                          request_id=int(request.request_id),
                          samples_kept=int(request.samples_kept),
                          learner_incarnation=str(request.learner_incarnation))
        try:
            self.table.sample(call, waiter=_QueryWaiter(pending, functools.partial(
                served_batch_to_bytes, request_id=call.request_id)),
                              timeout_s=self.config.replay.sample_timeout_s)
        except SampleRefused as exc:
            raise InvalidMessage(Reason.BAD_VALUE, str(exc)) from None

    # -- cluster model and eval results ----------------------------------------------------
    def _on_cluster_model(self, key: str, payload: bytes) -> None:
        try:
            msg = parse_message(payload, pb.ClusterModel,
                                max_bytes=self.config.replay.max_message_bytes)
            model = self._cluster_model(msg)
            adopted = self.table.adopt_cluster_model(model, msg)
        except EpisodeLogError as exc:  # adopted, not logged: a restart re-adopts an older one
            self.warn.warn("log:cluster_model", f"cluster model v{msg.version} adopted but not "
                           f"logged: {exc}")
            return
        except (InvalidMessage, ValueError) as exc:
            reason = exc.reason if isinstance(exc, InvalidMessage) else Reason.BAD_VALUE
            self._on_reject(InvalidMessage(reason, f"ClusterModel: {exc}"))
            return
        if adopted:
            log.info("cluster model v%d adopted; cluster sizes %s", model.version,
                     self.table.cluster_sizes())

    def _cluster_model(self, msg: pb.ClusterModel) -> ClusterModel:
        validate_centroids(msg, k=self.config.cluster.k, goal_dim=self.spec.goal_dim)
        if msg.version > MAX_SEQUENCE:  # checked before adopting: the log could not hold it
            raise InvalidMessage(Reason.BAD_VALUE,
                                 f"ClusterModel.version {msg.version} is above {MAX_SEQUENCE}, "
                                 "the largest the episode log holds")
        return msg_to_cluster_model(msg)

    def _on_clusterer_state(self, payload: bytes) -> bytes:
        parse_message(payload, pb.ClustererStateRequest,
                      max_bytes=self.config.replay.max_message_bytes)
        snap = self.table.clusterer_state()
        return pb.ClustererState(
            schema_version=SCHEMA_VERSION, failed_goals=array_to_msg(snap.failed_goals),
            failures_seen=snap.failures_seen, episodes_seen=snap.episodes_seen,
            model_version=snap.model_version).SerializeToString()

    def _on_eval_result(self, key: str, payload: bytes) -> None:
        try:
            msg = parse_message(payload, pb.EvalResult,
                                max_bytes=self.config.replay.max_message_bytes)
            validate_eval_result(msg)
            if msg.epoch > MAX_SEQUENCE:
                raise InvalidMessage(Reason.BAD_VALUE,
                                     f"EvalResult.epoch {msg.epoch} is above {MAX_SEQUENCE}, "
                                     "the largest the episode log holds")
        except InvalidMessage as exc:
            self._on_reject(exc)
            return
        try:
            self.table.log_eval_result(msg)
        except EpisodeLogError as exc:  # metrics.csv (the learner's) still gets the row
            self.warn.warn("log:eval_result", f"eval result of epoch {msg.epoch} not logged: "
                           f"{exc}")

    # -- status ----------------------------------------------------------------------------
    def status(self) -> pb.ReplayStatus:
        return counters_to_msg(self.table.status())

    def tick(self) -> None:
        """Once a second: expire parked calls past their deadline, put the status."""
        expired = self.table.expire()
        if expired:
            self.warn.warn("expired", f"{expired} parked call(s) outlived their caller's "
                                      "timeout and were dropped (the callers retry)")
        self.status_pub.put(self.status().SerializeToString())

    def close(self) -> None:
        self.log.close()


def run(config: HercsConfig, *, ident: str | None = None) -> int:
    """`hercs replay`: serve the run's replay until SIGTERM/SIGINT."""
    return service_main(role="replay", config=config, ident=ident or "replay", body=_work)


def saved_epsilon(config: HercsConfig, saved: Path) -> HercsConfig:
    """`config` with the ε written out: where it leaves ε unset and the run saved a config
    with a number, that number (a compose run resumed with HERCS_RESUME rebuilds its config
    from flags, and a run made before v4's default ε changed must keep its own), else its
    environment's default. The services get it from here (`join_run`)."""
    if config.energy.epsilon is None and saved.is_file():
        try:
            epsilon = load_yaml(saved).energy_epsilon
        except (ConfigError, OSError) as exc:
            log.warning("%s: not read for its energy.epsilon (%s); using the default", saved,
                        exc)
        else:
            return replace(config, energy=replace(config.energy, epsilon=epsilon))
    return config.resolved()


def _work(runtime: ServiceRuntime) -> int:
    run_dir = run_dir_of(runtime.config.run)
    run_dir.mkdir(parents=True, exist_ok=True)
    config = saved_epsilon(runtime.config, RunDir(run_dir).config)
    if not RunDir(run_dir).config.exists():  # `hercs up` writes it; compose runs do not
        save_yaml(config, RunDir(run_dir).config)
    service = ReplayService(config=config, runtime=runtime, run_dir=run_dir)
    log.info("replay serving run %s (%s, %s), capacity %d episodes", config.run.name,
             config.task.name, config.run.method, config.capacity_episodes)
    try:
        while not runtime.stop.wait(STATUS_PERIOD_S):
            service.tick()
    finally:
        runtime.transport.close()  # answers parked queries `unavailable` first
        service.close()
    return 0
