"""Appending to the run log: `EpisodeLogWriter`, one MCAP segment whose every append is on disk
when it returns (docs/DESIGN.md §3, "durable before ack"; §6, the MCAP log).

Each append is one zstd chunk, then fsync; `append_many` is the group commit. Scenes, derived
data and about two thirds of an append's CPU, are built and written on a background thread
without fsync: a crash can lose the last scenes, never an
episode; past `SCENE_BACKLOG` waiting episodes new ones get no scene.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import IO, NamedTuple

from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.message import Message
from mcap.well_known import MessageEncoding
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import register_schema

from hercs.proto import hercs_pb2 as pb
from hercs.proto.schema import SCHEMA_VERSION
from hercs.rl.task_registry import task_spec
from hercs.rl.task_spec import TaskSpec
from hercs.run.runlog import scene, scene_wire
from hercs.run.runlog.format import (
    CHUNK_BYTES,
    MAX_SEQUENCE,
    METADATA_NAME,
    START_TIME_KEY,
    TOPIC_CLUSTER_MODEL,
    TOPIC_EPISODES,
    TOPIC_EVAL_RESULT,
    TOPIC_REPLAY_STATE,
    TOPIC_SCENE,
    TOPIC_SCENE_POINTS,
    EpisodeLogError,
    fsync_dir,
    u32,
)
from hercs.run.runlog.mcap_bulk import add_message_rows, reuse_zstd_contexts
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.codec import msg_to_array

log = logging.getLogger(__name__)

if not hasattr(McapWriter, "flush"):  # durability rests on it: fail at import, not at an ack
    raise ImportError("hercs.run.runlog.writer needs mcap.writer.Writer.flush() "
                      "(mcap >= 1.6); upgrade the mcap package")


reuse_zstd_contexts()  # every append compresses a chunk: ~0.15 ms less each
_SCENE_UPDATE, _POINT_CLOUD = SceneUpdate(), PointCloud()
"""Instances naming the scene topics' message types (their schemas); the scene's messages
themselves are built as bytes (`hercs.run.runlog.scene_wire`)."""

SCENE_BACKLOG = 1024
"""Episodes whose scene may wait to be written; beyond it new episodes get none."""


class _PreparedEpisode(NamedTuple):
    episode_id: int
    msg: pb.Episode
    positions: scene.EpisodePositions
    times_ns: list[int]


class EpisodeLogWriter:
    """Appends episodes (with their Foxglove scene), cluster models and eval results to a new
    MCAP file; every append is on disk (fsync) when it returns.

    Thread-safe: appends are serialised by a lock. If an append raises after it started
    writing, the file may end in a torn record: the writer refuses further appends (reopen the
    log with `EpisodeLog.open`, which recovers everything appended before). Invalid input
    (bad arrays, an episode id not above the last one) raises before anything is written and
    leaves the writer usable.
    """

    def __init__(self, path: str | os.PathLike[str], *, run: str, task: str,
                 start_time_ns: int | None = None, scene: bool = True,
                 spec: TaskSpec | None = None,
                 compression: CompressionType = CompressionType.ZSTD) -> None:
        """`start_time_ns` is the run's start (ns since the Unix epoch; default now): the
        origin of the synthetic timeline, kept in the metadata so that a later segment of the
        same run continues it (`segments.run_start_ns`). `spec`: the run's task as configured
        (its horizon, `task.episode_steps`); default `task_spec(task)`."""
        self.path = Path(path)
        self.run = run
        self.task = task
        self.start_time_ns = time.time_ns() if start_time_ns is None else int(start_time_ns)
        if self.start_time_ns < 0:
            raise ValueError(f"start_time_ns={start_time_ns}: must be >= 0")
        self._spec = task_spec(task) if spec is None else spec
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._last_episode_id: int | None = None
        self._state = "open"
        self._durable_end = 0
        self._failure: BaseException | None = None
        """What made the writer fail (an append's, or the scene thread's, write error)."""
        self.scenes_dropped = 0
        """Episodes logged without a scene because the scene thread was too far behind."""
        self._scene_queue: queue.Queue[_PreparedEpisode | None] | None = None
        self._scene_thread: threading.Thread | None = None
        self._warn = WarnOncePerMinute(log)
        try:
            self._file: IO[bytes] = open(self.path, "xb")  # noqa: SIM115 (closed in close())
        except FileExistsError:
            raise EpisodeLogError(
                f"{self.path} already exists; an episode log is never overwritten. Use "
                "EpisodeLog.open(run_dir) to recover it and continue in a new segment"
            ) from None
        try:
            self._mcap = McapWriter(self._file, chunk_size=CHUNK_BYTES,
                                    compression=compression)
            self._mcap.start(library=f"hercs episode_log, {LIBRARY_IDENTIFIER}")
            self._mcap.add_metadata(METADATA_NAME, {
                "run": run, "task": task, "schema_version": str(SCHEMA_VERSION),
                START_TIME_KEY: str(self.start_time_ns)})
            self._sync()
            fsync_dir(self.path.parent)
        except BaseException:  # e.g. a full disk: the next EpisodeLog.open removes the stub
            with contextlib.suppress(OSError):
                self._file.close()
            raise
        if scene and self._spec.goal_points > 0:
            self._scene_queue = queue.Queue(maxsize=SCENE_BACKLOG)
            self._scene_thread = threading.Thread(target=self._write_scenes, daemon=True,
                                                  name=f"scene-writer:{self.path.name}")
            self._scene_thread.start()

    @property
    def failed(self) -> bool:
        """An append failed while writing: nothing more can be appended to this file."""
        return self._state == "failed"

    @property
    def durable_end(self) -> int:
        """File offset just past the last append that returned. After a failed append the
        bytes beyond it belong to no acked message, even a complete chunk that reached the
        disk before a later write failed: cutting them keeps the log equal to what was acked
        (`RecoveringLogWriter` does, so that the failed episode's id can be used again)."""
        return self._durable_end

    def append_episode(self, msg: pb.Episode, *, episode_id: int,
                       log_time_ns: int | None = None) -> None:
        """Log one episode and its per-step scene; durable when this returns.

        `log_time_ns` is the wall-clock time of the insert (default now), stored as the
        messages' publish_time; their log_time is the synthetic timeline (module docstring).
        """
        self.append_many([(episode_id, msg)], log_time_ns=log_time_ns)

    def append_many(self, episodes: Sequence[tuple[int, pb.Episode]], *,
                    log_time_ns: int | None = None) -> None:
        """Group commit: log `(episode_id, Episode)` pairs, ids strictly increasing, as one
        chunk with one fsync; all are durable when this returns, none may be acked before."""
        wall = time.time_ns() if log_time_ns is None else int(log_time_ns)
        with self._lock:
            self._check_writable()
            prepared = self._prepare(episodes)
            start = self.start_time_ns
            self._write_durably(
                (TOPIC_EPISODES, episode.msg,
                 start + scene.episode_start_ns(episode.episode_id, self._spec.episode_steps),
                 wall, episode.episode_id)
                for episode in prepared)
            if prepared:
                self._last_episode_id = prepared[-1].episode_id
        for episode in prepared:
            self._queue_scene(episode)

    def flush_scenes(self) -> None:
        """Return when every scene queued so far is written (tests, close)."""
        if self._scene_queue is not None:
            self._scene_queue.join()

    def append_cluster_model(self, msg: pb.ClusterModel, *, log_time_ns: int | None = None
                             ) -> None:
        """Log a cluster model (sequence = its version); durable when this returns."""
        self._append_other(TOPIC_CLUSTER_MODEL, msg, u32(msg.version, "ClusterModel.version"),
                           log_time_ns)

    def append_eval_result(self, msg: pb.EvalResult, *, log_time_ns: int | None = None) -> None:
        """Log an evaluation result (sequence = its epoch); durable when this returns."""
        self._append_other(TOPIC_EVAL_RESULT, msg, u32(msg.epoch, "EvalResult.epoch"),
                           log_time_ns)

    def append_replay_state(self, msg: pb.ReplayState) -> None:
        """Log the replay's state as of episode `msg.next_episode_id` (its sequence); durable
        when this returns. Later episodes of this file must have ids from that one on."""
        next_id = u32(msg.next_episode_id, "ReplayState.next_episode_id")
        wall = time.time_ns()
        with self._lock:
            self._check_writable()
            if self._last_episode_id is not None and self._last_episode_id >= next_id:
                raise ValueError(f"ReplayState.next_episode_id={next_id}: episode "
                                 f"{self._last_episode_id} is logged here already; nothing "
                                 "was written")
            at = self.start_time_ns + (scene.episode_start_ns(next_id, self._spec.episode_steps)
                                       - scene.STEP_NS if next_id else 0)
            self._write_durably([(TOPIC_REPLAY_STATE, msg, at, wall, next_id)])
            if next_id:
                self._last_episode_id = next_id - 1

    def move_to(self, path: str | os.PathLike[str]) -> None:
        """Rename the file while it is open (a live segment becoming a numbered one); pending
        scenes and `close()` go on writing to it. The caller fsyncs the directory."""
        with self._lock:
            os.rename(self.path, path)
            self.path = Path(path)

    def close(self) -> None:
        """Write the pending scenes, the summary (index, statistics) and footer, fsync and
        close. Idempotent. A writer that failed mid-append is closed without a footer
        (recovery seals it)."""
        if self._scene_thread is not None and self._scene_queue is not None:
            self._scene_queue.put(None)  # after every queued scene
            self._scene_thread.join()
            self._scene_thread = None
        with self._lock:
            if self._state == "closed":
                return
            failed, self._state = self._state == "failed", "closed"
            if failed:
                try:
                    self._file.close()  # may retry the write that failed
                except OSError as exc:
                    log.warning("%s: closing after a failed append: %s", self.path, exc)
                return
            try:
                self._mcap.finish()
                self._file.flush()
                os.fsync(self._file.fileno())
            except OSError as exc:  # e.g. a full disk: every append is already on disk
                log.warning("%s: could not write the summary and footer (%s); every append "
                            "is on disk, and the next EpisodeLog.open seals the file",
                            self.path, exc)
            finally:
                with contextlib.suppress(OSError):
                    self._file.close()

    def __enter__(self) -> EpisodeLogWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- internals ---------------------------------------------------------------------------

    def _check_writable(self) -> None:
        if self._state == "closed":
            raise EpisodeLogError(f"{self.path}: append after close(); nothing was written")
        if self._state == "failed":
            raise EpisodeLogError(
                f"{self.path}: an earlier write failed ({self._failure!r}), so the file may "
                "end in a torn record; nothing more is appended. Reopen with "
                "EpisodeLog.open(run_dir)") from self._failure

    def _prepare(self, episodes: Sequence[tuple[int, pb.Episode]]) -> list[_PreparedEpisode]:
        """Check ids and arrays before the first byte is written."""
        prepared = []
        last = self._last_episode_id
        for episode_id, msg in episodes:
            episode_id = int(episode_id)
            if not 0 <= episode_id <= MAX_SEQUENCE:
                raise ValueError(f"episode_id={episode_id}: must be in [0, {MAX_SEQUENCE}] "
                                 "(it is stored as the uint32 MCAP message sequence)")
            if last is not None and episode_id <= last:
                raise ValueError(f"episode_id={episode_id}: ids must increase, the last logged "
                                 f"id is {last}; nothing was written")
            if (msg.run, msg.task) != (self.run, self.task):
                raise ValueError(f"episode_id={episode_id}: Episode of run {msg.run!r} task "
                                 f"{msg.task!r} in the log of run {self.run!r} task "
                                 f"{self.task!r}; nothing was written")
            last = episode_id
            obs = msg_to_array(msg.obs, where="Episode.obs")
            positions = scene.episode_positions(  # checks the shapes now, not in the thread
                obs, msg_to_array(msg.ag, where="Episode.ag"),
                msg_to_array(msg.g, where="Episode.g"), self._spec)
            times = [self.start_time_ns + t for t in scene.step_times_ns(
                episode_id, len(obs), self._spec.episode_steps)]
            prepared.append(_PreparedEpisode(episode_id, msg, positions, times))
        return prepared

    def _scene_messages(self, episode: _PreparedEpisode) -> tuple[list[bytes], list[bytes]]:
        """One episode's scene: its `/scene` and `/scene/points` messages, one per step."""
        positions, times, msg = episode.positions, episode.times_ns, episode.msg
        labels = {"episode_id": str(episode.episode_id), "actor_id": msg.actor_id,
                  "seq": str(msg.seq), "success": str(bool(msg.success)).lower()}
        return (scene_wire.scene_updates(positions, times,
                                         goal_diameter=2 * self._spec.distance_threshold,
                                         labels=labels),
                scene_wire.point_clouds(positions, times))

    def _queue_scene(self, episode: _PreparedEpisode) -> None:
        if self._scene_queue is None:
            return
        try:
            self._scene_queue.put_nowait(episode)
        except queue.Full:
            self.scenes_dropped += 1
            self._warn.warn("scenes dropped", f"{self.path}: episodes arrive faster than their "
                            f"scenes can be drawn; {self.scenes_dropped} episodes so far logged "
                            "without a scene (the episodes themselves are all logged)")

    def _write_scenes(self) -> None:
        """The scene thread: build each queued episode's scene and append it (no fsync)."""
        assert self._scene_queue is not None
        while True:
            episode = self._scene_queue.get()
            try:
                if episode is None:
                    return
                # built and serialised outside the lock; only the chunk write holds it
                columns = self._scene_messages(episode)
                with self._lock:
                    if self._state == "open":
                        self._write_rows(episode, columns)
            except Exception as exc:  # a failed write marks the writer failed; log and go on
                log.warning("%s: scene of episode %s not written: %s", self.path,
                            None if episode is None else episode.episode_id, exc)
            finally:
                self._scene_queue.task_done()

    def _append_other(self, topic: str, msg: Message, sequence: int,
                      log_time_ns: int | None) -> None:
        wall = time.time_ns() if log_time_ns is None else int(log_time_ns)
        with self._lock:
            self._check_writable()
            self._write_durably([(topic, msg, self._gap_time_ns(), wall, sequence)])

    def _gap_time_ns(self) -> int:
        """The empty slot after the last episode written here: between it and the next one."""
        if self._last_episode_id is None:
            return self.start_time_ns
        return (self.start_time_ns
                + scene.episode_start_ns(self._last_episode_id + 1, self._spec.episode_steps)
                - scene.STEP_NS)

    def _write_durably(self, records: Iterable[tuple[str, Message, int, int, int]]) -> None:
        """Append `records` as one chunk, fsync and move the durable end."""
        try:
            for topic, msg, log_time, publish_time, sequence in records:
                self._mcap.add_message(channel_id=self._channel(topic, msg), log_time=log_time,
                                       data=msg.SerializeToString(),
                                       publish_time=publish_time, sequence=sequence)
            self._sync()
        except BaseException as exc:
            self._state, self._failure = "failed", exc
            raise

    def _write_rows(self, episode: _PreparedEpisode, columns: tuple[list[bytes], list[bytes]]
                    ) -> None:
        """Append one episode's scene (`mcap_bulk`: the step's update, then its points, step
        by step, as `add_message` would) as one chunk, without fsync."""
        try:
            channels = (self._channel(TOPIC_SCENE, _SCENE_UPDATE),
                        self._channel(TOPIC_SCENE_POINTS, _POINT_CLOUD))
            add_message_rows(self._mcap, channels, episode.times_ns, episode.episode_id,
                             columns)
            self._mcap.flush()  # closes the chunk; the next sync makes it durable too
        except BaseException as exc:
            self._state, self._failure = "failed", exc
            raise

    def _channel(self, topic: str, msg: Message) -> int:
        channel_id = self._channels.get(topic)
        if channel_id is None:
            name = msg.DESCRIPTOR.full_name
            schema_id = self._schemas.get(name)
            if schema_id is None:
                schema_id = self._schemas[name] = register_schema(self._mcap, type(msg))
            channel_id = self._channels[topic] = self._mcap.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=schema_id)
        return channel_id

    def _sync(self) -> None:
        self._mcap.flush()  # closes the chunk, writes it and flushes the Python buffer
        os.fsync(self._file.fileno())
        self._durable_end = self._file.tell()
