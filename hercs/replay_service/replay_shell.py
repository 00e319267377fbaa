"""`hercs replay`: the replay service process, a thin Zenoh shell around `ReplayTable`.

It decodes and validates each query and hands it to the table with a waiter that answers it,
now or later; every decision is the table's. Queries are served on our own worker threads,
never inside Zenoh callbacks; `replay/status` is put about once a second (and
`replay/status_at` answers with the counters of a served batch's moment), and parked calls
past their caller's timeout are answered `expired` at that pace. On start the episode log is
replayed into the table (from its newest saved state, for a bounded log), so nothing acked is
lost across a restart; the limiter restarts balanced at the recovered size and the log's
newest cluster model is adopted again (docs/DESIGN.md §6, §8).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, TypeVar

from hercs.config import HercsConfig, save_yaml
from hercs.errors import InvalidMessage
from hercs.net.service_shell import ServiceRuntime, service_main
from hercs.net.transport import PendingReply
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.builder import ReplayBuilder, saved_epsilon
from hercs.replay_service.replay_messages import (
    check_eval_result,
    cluster_model,
    clusterer_state,
    insert_ack,
    inserted_header,
    sample_call,
    unknown_episode,
)
from hercs.replay_service.table import SampleRefused, Stored
from hercs.rl.cluster_model import ClusterModel
from hercs.run.rundir import RunDir, run_dir_of
from hercs.run.runlog import (
    EpisodeLogError,
)
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.codec import (
    episode_to_msg,
)
from hercs.wire.served import counters_to_msg, served_batch_to_bytes
from hercs.wire.validation import (
    decode_episode,
    parse_message,
)

log = logging.getLogger("hercs.replay")

STATUS_PERIOD_S = 1.0
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

    def __init__(self, *, parts: ReplayBuilder, runtime: ServiceRuntime, run_dir: Path) -> None:
        self.settings = settings = parts.shell
        self.runtime = runtime
        self.spec = settings.spec
        self.warn = WarnOncePerMinute(log)
        self.log, self.table = parts.open_table(run_dir)

        keys, transport = runtime.keys, runtime.transport
        self.inserted_pub = transport.publisher(keys.inserted, block=True)
        self.status_pub = transport.publisher(keys.status)
        transport.serve(keys.config, lambda _: settings.config_yaml)
        transport.serve(keys.episode, self._on_episode_request,
                        on_error=self._on_episode_request_error)
        transport.serve(keys.clusterer_state, self._on_clusterer_state, on_error=self._on_reject)
        transport.serve(keys.status_at, self._on_status_at, on_error=self._on_reject)
        transport.subscribe(keys.cluster_model, self._on_cluster_model, latest=True)
        transport.subscribe(keys.eval_result, self._on_eval_result)
        transport.serve_deferred(keys.insert, self._on_insert, on_error=self._on_reject,
                                 workers=settings.insert_workers)
        transport.serve_deferred(keys.sample, self._on_sample, on_error=self._on_reject)

    # -- inserts ---------------------------------------------------------------------------
    def _on_reject(self, exc: Exception) -> None:
        reason = exc.reason if isinstance(exc, InvalidMessage) else Reason.INTERNAL
        self.table.count_reject(reason)
        self.warn.warn(f"reject:{reason}", f"rejected a message: {exc}")

    def _on_insert(self, pending: PendingReply) -> None:
        msg, episode = decode_episode(pending.payload, self.spec, run=self.settings.run,
                                      max_bytes=self.settings.max_message_bytes)
        self.table.insert(episode, record=msg,
                          waiter=_QueryWaiter(pending, self._acked),
                          timeout_s=self.settings.insert_timeout_s)

    def _acked(self, stored: Stored) -> bytes:
        """The ack's bytes; a newly stored episode is also announced on `replay/inserted`."""
        if not stored.duplicate:
            self.inserted_pub.put(inserted_header(stored).SerializeToString())
        return insert_ack(stored).SerializeToString()

    # -- stored episodes (the live view) ---------------------------------------------------
    def _on_episode_request(self, payload: bytes) -> bytes:
        request = parse_message(payload, pb.EpisodeRequest,
                                max_bytes=self.settings.max_message_bytes)
        episode_id = int(request.episode_id)
        episode, first, end = self.table.stored_episode(episode_id)
        if episode is None:
            raise unknown_episode(episode_id, first, end)
        return episode_to_msg(episode, run=self.settings.run,
                              task=self.spec.name).SerializeToString()

    def _on_episode_request_error(self, exc: Exception) -> None:
        if isinstance(exc, InvalidMessage) and exc.reason == Reason.UNKNOWN_EPISODE:
            log.debug("episode request: %s", exc)
            return
        self._on_reject(exc)

    # -- samples ---------------------------------------------------------------------------
    def _on_sample(self, pending: PendingReply) -> None:
        request = parse_message(pending.payload, pb.SampleRequest,
                                max_bytes=self.settings.max_message_bytes)
        call = sample_call(request, run=self.settings.run)
        try:
            self.table.sample(call, waiter=_QueryWaiter(pending, functools.partial(
                served_batch_to_bytes, request_id=call.request_id)),
                              timeout_s=self.settings.sample_timeout_s)
        except SampleRefused as exc:
            raise InvalidMessage(Reason.BAD_VALUE, str(exc)) from None

    # -- cluster model and eval results ----------------------------------------------------
    def _on_cluster_model(self, key: str, payload: bytes) -> None:
        try:
            msg = parse_message(payload, pb.ClusterModel,
                                max_bytes=self.settings.max_message_bytes)
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
        return cluster_model(msg, k=self.settings.clusters, goal_dim=self.spec.goal_dim)

    def _on_clusterer_state(self, payload: bytes) -> bytes:
        parse_message(payload, pb.ClustererStateRequest,
                      max_bytes=self.settings.max_message_bytes)
        return clusterer_state(self.table.clusterer_state()).SerializeToString()

    def _on_eval_result(self, key: str, payload: bytes) -> None:
        try:
            msg = parse_message(payload, pb.EvalResult,
                                max_bytes=self.settings.max_message_bytes)
            check_eval_result(msg)
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

    def _on_status_at(self, payload: bytes) -> bytes:
        request = parse_message(payload, pb.ReplayStatusRequest,
                                max_bytes=self.settings.max_message_bytes)
        return counters_to_msg(self.table.status_at(int(request.samples))).SerializeToString()

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


def _work(runtime: ServiceRuntime) -> int:
    run_dir = run_dir_of(runtime.config.run)
    run_dir.mkdir(parents=True, exist_ok=True)
    config = saved_epsilon(runtime.config, RunDir(run_dir).config)
    if not RunDir(run_dir).config.exists():  # `hercs up` writes it; compose runs do not
        save_yaml(config, RunDir(run_dir).config)
    service = ReplayService(parts=ReplayBuilder(config), runtime=runtime, run_dir=run_dir)
    settings = service.settings
    log.info("replay serving run %s (%s, %s), capacity %d episodes", settings.run,
             settings.task, settings.method, service.table.store.capacity_episodes)
    try:
        while not runtime.stop.wait(STATUS_PERIOD_S):
            service.tick()
    finally:
        runtime.transport.close()  # answers parked queries `unavailable` first
        service.close()
    return 0
