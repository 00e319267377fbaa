"""`hercs live`: a run streamed to Rerun while it trains (docs/DESIGN.md §6), `hercs up --rerun`.

The shell: sinks, subscriptions, episode queries and the loop (`LiveViewService`);
`LiveRecorder` (views/live_recorder.py) draws, with views/rerun_draw.py as `hercs view`
does; the recording id is the run name, so a restarted live view continues the same
recording. It never holds up or fails training (`hercs up` treats it as optional):
subscriptions only queue bytes; a lost viewer is reported once (again only after it came back)
while any .rrd keeps being written; a bad message or a failed query is logged and skipped.
"""

from __future__ import annotations

import logging
import queue
import time
from collections.abc import Callable

from hercs.apps.views.live_recorder import LiveRecorder
from hercs.apps.views.live_sinks import ViewerHealth, close_recording, open_recording
from hercs.config import HercsConfig
from hercs.errors import InvalidMessage
from hercs.net.service_shell import ServiceRuntime, join_run, service_main
from hercs.net.transport import RemoteError, TransportError
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.validation import (
    parse_message,
    validate_episode,
)

log = logging.getLogger("hercs.live")

EPISODE_TIMEOUT_S = 2.0
FINAL_FETCH_S = 3.0
"""On stop, the headers already received are still drawn, and their wanted trajectories
fetched for at most this long: the replay stops after the live view (`hercs up`'s stop
order), so the recording keeps the run's last drawn episodes."""
FLUSH_PERIOD_S = 5.0
METRICS_PERIOD_S = 5.0
_POLL_S = 0.25
_MAX_BATCH = 512
_HEADER_MAX_BYTES = 64 * 1024


# --------------------------------------------------------------------------------------------
# The shell: Zenoh subscriptions, the episode queries, the loop


class Inbox:
    """The subscriptions; their threads only queue `(kind, payload)` (never block, never
    decode), so a slow viewer or query never holds up Zenoh."""

    def __init__(self, runtime: ServiceRuntime) -> None:
        self.items: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        keys, transport = runtime.keys, runtime.transport
        transport.subscribe(keys.inserted, self._put("header"), capacity=1024)
        transport.subscribe(keys.cluster_model, self._put("model"), latest=True)
        transport.subscribe(keys.all_metrics, self._put("metrics"))
        transport.subscribe(keys.status, self._put("status"), drop_oldest=True, capacity=4)

    def _put(self, kind: str) -> Callable[[str, bytes], None]:
        def put(key: str, payload: bytes) -> None:
            self.items.put((kind, payload))

        return put

    def take(self, timeout_s: float) -> list[tuple[str, bytes]]:
        """What arrived, up to `_MAX_BATCH` items; waits up to `timeout_s` for the first."""
        try:
            batch = [self.items.get(timeout=timeout_s) if timeout_s > 0
                     else self.items.get_nowait()]
        except queue.Empty:
            return []
        while len(batch) < _MAX_BATCH:
            try:
                batch.append(self.items.get_nowait())
            except queue.Empty:
                break
        return batch


class LiveViewService:
    """The main loop around a `LiveRecorder`; `run()` returns when `runtime.stop` is set.

    What each message becomes in the recording:

        metrics/**        the learner's per-epoch `Metrics` (with `epoch`): every finite value
                          but `epoch`/`epochs` → `curves/<name>` on `epoch`, and on `episode` at
                          the epoch's last episode; other services' metrics carry no epoch and
                          are ignored
        replay/status     the latest cluster sizes → `curves/cluster_sizes` at each epoch
        replay/inserted   each `EpisodeHeader` → `episodes/success`, `episodes/final_distance`,
                          `episodes/cluster` on `episode`; a failed episode's goal joins the
                          failed goals
        cluster/model     (latest, as a late joiner) → `world/centroids`, `log/cluster_models`
                          and the failed goals recoloured, at the episode after the last header
                          seen (a model that came before any header: at the first header)
        replay/episode    (query) the `Episode` of every multiple of `view.episode_every` →
                          `world/episodes/<id>/{gripper,object,goal}` on `step` and `episode`,
                          `log/episodes`; `world/failed_goals` is logged at those ids too (and at
                          each model), so scrubbing `episode` shows it grow
    """

    def __init__(self, *, runtime: ServiceRuntime, config: HercsConfig, inbox: Inbox,
                 recorder: LiveRecorder) -> None:
        self.runtime = runtime
        self.config = config
        self.inbox = inbox
        self.recorder = recorder
        self.max_bytes = config.replay.max_message_bytes
        self.rejected = 0
        self.fetch_failures = 0
        self.viewer = ViewerHealth(recorder.rec, viewer=config.view.viewer,
                                   save=config.view.save)
        self._warn = WarnOncePerMinute(log)

    def step(self, timeout_s: float, *, fetch: bool = True) -> int:
        """Handle what arrived (waiting up to `timeout_s` for something); returns how many
        messages. Wanted trajectories are fetched after the batch, unless `fetch` is False."""
        batch = self.inbox.take(timeout_s)
        wanted = []
        for kind, payload in batch:
            try:
                if kind == "header":
                    header = parse_message(payload, pb.EpisodeHeader,
                                           max_bytes=_HEADER_MAX_BYTES)
                    if self.recorder.on_header(header):
                        wanted.append(int(header.episode_id))
                elif kind == "model":
                    self.recorder.on_cluster_model(
                        parse_message(payload, pb.ClusterModel, max_bytes=self.max_bytes))
                elif kind == "metrics":
                    self.recorder.on_metrics(
                        parse_message(payload, pb.Metrics, max_bytes=self.max_bytes))
                else:
                    self.recorder.on_status(
                        parse_message(payload, pb.ReplayStatus, max_bytes=self.max_bytes))
            except InvalidMessage as exc:
                self.rejected += 1
                self._warn.warn(f"{kind}:{exc.reason}", f"skipped a {kind} message: {exc}")
        self.recorder.commit()
        for episode_id in wanted:
            if fetch:
                self.fetch(episode_id)
            else:
                self.recorder.forget(episode_id)
        return len(batch)

    def fetch(self, episode_id: int) -> bool:
        """Ask the replay for episode `episode_id` and draw it; False (logged) if it could not."""
        request = pb.EpisodeRequest(schema_version=SCHEMA_VERSION, episode_id=episode_id)
        try:
            raw = self.runtime.transport.request(self.runtime.keys.episode,
                                                 request.SerializeToString(),
                                                 timeout_s=EPISODE_TIMEOUT_S)
            msg = parse_message(raw, pb.Episode, max_bytes=self.max_bytes)
            validate_episode(msg, self.recorder.spec)
        except (TransportError, InvalidMessage) as exc:
            self.fetch_failures += 1
            self.recorder.forget(episode_id)
            reason = (exc.reason if isinstance(exc, RemoteError | InvalidMessage)
                      else Reason.TRANSPORT)
            self._warn.warn(f"fetch:{reason}", f"no trajectory for episode {episode_id}: {exc}")
            return False
        self.recorder.on_episode(msg, episode_id=episode_id)
        return True

    def publish_metrics(self) -> None:
        values = {"headers": self.recorder.headers, "trajectories": self.recorder.trajectories,
                  "models": self.recorder.models, "epochs": self.recorder.epochs,
                  "rejected": self.rejected, "fetch_failures": self.fetch_failures,
                  "viewer_errors": self.viewer.errors, "inbox": self.inbox.items.qsize()}
        try:
            self.runtime.publish_metrics(values)
        except TransportError as exc:  # metrics are best effort
            self._warn.warn("metrics", f"could not publish metrics: {exc}")

    def run(self) -> int:
        stop = self.runtime.stop
        self.recorder.start()
        now = time.monotonic()
        next_flush, next_metrics = now + FLUSH_PERIOD_S, now + METRICS_PERIOD_S
        while not stop.is_set():
            self.step(_POLL_S)
            now = time.monotonic()
            if now >= next_flush:
                self.viewer.check()
                next_flush = now + FLUSH_PERIOD_S
            if now >= next_metrics:
                self.publish_metrics()
                next_metrics = now + METRICS_PERIOD_S
        deadline = time.monotonic() + FINAL_FETCH_S
        while self.step(0.0, fetch=time.monotonic() < deadline):  # what already arrived
            pass
        self.publish_metrics()
        log.info("live view done: %d episodes, %d trajectories, %d cluster models, %d epochs",
                 self.recorder.headers, self.recorder.trajectories, self.recorder.models,
                 self.recorder.epochs)
        return 0


def run(config: HercsConfig, *, ident: str | None = None) -> int:
    """`hercs live`: stream `config.run.name` to Rerun until SIGTERM/SIGINT. The run's config
    comes from its replay (as for a remote actor); the local `view` section is kept."""
    return service_main(role="live", config=config, ident=ident, body=_work)


def _work(runtime: ServiceRuntime) -> int:
    inbox = Inbox(runtime)  # before anything slow: headers from now on are kept
    joined = join_run(runtime, runtime.config, keep=("transport", "security", "view"))
    if joined is None:  # stopped first
        return 0
    import rerun as rr  # imported here: `hercs --help` stays fast

    rec = open_recording(rr, joined)
    try:
        recorder = LiveRecorder(rr, rec, spec=joined.task.spec, k=joined.cluster.k,
                                episode_every=joined.view.episode_every)
        log.info("live view of run %s (%s, %s): viewer %s%s, trajectories of the episode ids "
                 "that are multiples of %d (0 = none)", joined.run.name, joined.task.name,
                 joined.run.method, joined.view.viewer,
                 f", saving {joined.view.save}" if joined.view.save else "",
                 joined.view.episode_every)
        return LiveViewService(runtime=runtime, config=joined, inbox=inbox,
                               recorder=recorder).run()
    finally:
        runtime.close()
        close_recording(rec)
