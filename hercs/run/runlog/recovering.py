"""A run-log writer that outlives a full disk: `RecoveringLogWriter`.

An `EpisodeLogWriter` whose append failed part way may end in a torn record and refuses every
later append; the replay must neither stay unable to log (and so to ack) once space returns,
nor crash when it stops or restarts on a full disk. So after a failed append this writer cuts
the torn segment back to the last append that returned (the failed one was never acked; its id
goes to the next episode) and continues in a new segment (tried at most once per `retry_s`);
until then every append raises `EpisodeLogError`, the replay refuses the insert and the actor
retries. Nothing is acked that is not on disk. It also starts a bounded log's new segments
(`start_segment`); closing the old writer and pruning run on a background thread, off the ack
path.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_spec import TaskSpec
from hercs.run.runlog.format import EpisodeLogError
from hercs.run.runlog.pruning import prune_log
from hercs.run.runlog.segments import EpisodeLog, RecoveredLog, next_segment_path, run_start_ns
from hercs.run.runlog.writer import EpisodeLogWriter
from hercs.run.warn_once import WarnOncePerMinute

log = logging.getLogger(__name__)

RETRY_S = 1.0
"""How often appends try to start a new segment while the log is failed."""


class RecoveringLogWriter:
    """The replay's log sink (`append_episode`, `append_cluster_model`, `append_eval_result`,
    `close`); thread-safe. Open it with `RecoveringLogWriter.open`."""

    def __init__(self, run_dir: Path, *, run: str, task: str, retry_s: float = RETRY_S,
                 clock: Callable[[], float] = time.monotonic, scene: bool = True,
                 segment_episodes: int = 0, max_bytes: int = -1,
                 spec: TaskSpec | None = None) -> None:
        """`segment_episodes`: episodes per segment before `rotation_due` (0: never);
        `max_bytes`: the bound old segments are deleted under (-1: none; module docstring);
        `spec`: the run's task as configured (its horizon; default: `task_spec(task)`)."""
        self.run_dir = run_dir
        self.run = run
        self.task = task
        self.spec = spec
        self.scene = scene
        self.segment_episodes = segment_episodes
        self.max_bytes = max_bytes
        self.retry_s = retry_s
        self._clock = clock
        self._lock = threading.Lock()
        self._writer: EpisodeLogWriter | None = None
        self._failed_since: float | None = None
        self._error = ""
        self._next_try = 0.0
        self._closed = False
        self.recoveries = 0
        """New segments started after a failure."""
        self._state_from = 0
        """The next_episode_id of the log's newest replay state (0: none)."""
        self._appended_to = 0
        """One past the last episode id appended in this life (0: none yet)."""
        self._upkeep_lock = threading.Lock()  # taken after _lock, never before it
        self._retiring: list[EpisodeLogWriter] = []
        """Writers of segments numbered by `start_segment`, not closed yet."""
        self._upkeep: threading.Thread | None = None
        self._warn = WarnOncePerMinute(log)

    @classmethod
    def open(cls, run_dir: str | os.PathLike[str], *, run: str, task: str,
             retry_s: float = RETRY_S, clock: Callable[[], float] = time.monotonic,
             scene: bool = True, segment_episodes: int = 0, max_bytes: int = -1,
             spec: TaskSpec | None = None) -> tuple[RecoveringLogWriter, RecoveredLog]:
        """Like `EpisodeLog.open`, but a disk too full to start the new segment is not an
        error: the recovered episodes are returned all the same, and appends fail (and retry)
        until there is room."""
        self = cls(Path(run_dir), run=run, task=task, retry_s=retry_s, clock=clock,
                   scene=scene, segment_episodes=segment_episodes, max_bytes=max_bytes,
                   spec=spec)
        sealed = EpisodeLog.retire(self.run_dir, run=run, task=task)
        try:
            self._writer = EpisodeLogWriter(EpisodeLog(self.run_dir).live_path, run=run,
                                            task=task, start_time_ns=run_start_ns(sealed),
                                            scene=scene, spec=spec)
        except OSError as exc:
            self._fail(exc)
        recovered = EpisodeLog.recovered(sealed)
        if recovered.replay_state is not None:
            self._state_from = int(recovered.replay_state.next_episode_id)
        return self, recovered

    @property
    def failed(self) -> bool:
        """Appends are refused until a new segment can be started."""
        with self._lock:
            return self._failed_since is not None

    def append_episode(self, msg: pb.Episode, *, episode_id: int) -> None:
        self._append(lambda writer: writer.append_episode(msg, episode_id=episode_id))

    def append_many(self, episodes: list[tuple[int, pb.Episode]]) -> None:
        """Group commit: the episodes as one chunk with one fsync (`EpisodeLogWriter`)."""
        self._append(lambda writer: writer.append_many(episodes),
                     next_id=episodes[-1][0] + 1 if episodes else None)

    def append_cluster_model(self, msg: pb.ClusterModel) -> None:
        self._append(lambda writer: writer.append_cluster_model(msg))

    def append_eval_result(self, msg: pb.EvalResult) -> None:
        self._append(lambda writer: writer.append_eval_result(msg))

    def rotation_due(self) -> bool:
        """`segment_episodes` episodes logged since the newest state: time for
        `start_segment`."""
        with self._lock:
            return (0 < self.segment_episodes <= self._appended_to - self._state_from
                    and self._writer is not None and self._failed_since is None)

    def start_segment(self, state: pb.ReplayState) -> None:
        """Number the live segment and start a new one that begins with `state`, durable when
        this returns. The caller logs no episode meanwhile (the replay holds its commit lock),
        so `state` is exactly that of the episodes logged before it. The old segment is
        closed, and the log pruned, on the upkeep thread (module docstring).

        Raises EpisodeLogError if the new segment cannot be started; then appends fail and
        retry, as after any failed write, and nothing appended before is lost."""
        with self._lock:
            old = self._writer
            if old is None or self._failed_since is not None or self._closed:
                return
            try:
                old.move_to(next_segment_path(self.run_dir))
            except OSError as exc:
                raise EpisodeLogError(f"{old.path}: cannot number it ({exc}); it stays the "
                                      "live segment") from None
            self._writer = None
            with self._upkeep_lock:
                self._retiring.append(old)
            try:
                writer = EpisodeLogWriter(EpisodeLog(self.run_dir).live_path, run=self.run,
                                          task=self.task, start_time_ns=old.start_time_ns,
                                          scene=self.scene, spec=self.spec)
                self._writer = writer
                writer.append_replay_state(state)
                self._state_from = int(state.next_episode_id)
            except OSError as exc:  # appends fail and retry until a segment can be started
                self._fail(exc)
                raise EpisodeLogError(f"{self.run_dir}: cannot start a new log segment "
                                      f"({exc}); {old.path.name} keeps every episode appended "
                                      "so far") from None
            finally:
                self._start_upkeep()

    def flush_upkeep(self) -> None:
        """Return when every numbered segment is closed and the log pruned (tests, close)."""
        with self._upkeep_lock:
            upkeep = self._upkeep
        if upkeep is not None:
            upkeep.join()

    def close(self) -> None:
        """Close the live segment; never raises for a full disk (every append is on disk
        already; the next open seals what could not be sealed now). Idempotent."""
        with self._lock:
            self._closed = True
            writer, self._writer = self._writer, None
        if writer is not None:
            writer.close()
        self.flush_upkeep()

    def __enter__(self) -> RecoveringLogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals ---------------------------------------------------------------------------
    def _append(self, append: Callable[[EpisodeLogWriter], None], *,
                next_id: int | None = None) -> None:
        with self._lock:
            writer = self._usable_writer()
            try:
                append(writer)
            except Exception as exc:
                if writer.failed:  # torn: the next append after retry_s starts a new segment
                    self._fail(exc)
                raise
            if next_id is not None:
                self._appended_to = next_id

    def _start_upkeep(self) -> None:
        """Close the numbered segments' writers, then prune the log, on a new thread that
        first waits for the previous one (so the two never run at once)."""
        with self._upkeep_lock:
            previous = self._upkeep
            self._upkeep = threading.Thread(target=self._run_upkeep, args=(previous,),
                                            daemon=True, name=f"log-upkeep:{self.run_dir.name}")
            self._upkeep.start()

    def _run_upkeep(self, previous: threading.Thread | None) -> None:
        if previous is not None:
            previous.join()
        with self._upkeep_lock:
            retiring, self._retiring = self._retiring, []
        for writer in retiring:
            writer.close()  # pending scenes, summary, footer; never raises for a full disk
        if self.max_bytes < 0:
            return
        try:
            _, size = prune_log(self.run_dir, max_bytes=self.max_bytes)
        except (OSError, EpisodeLogError) as exc:  # the next segment tries again
            self._warn.warn("prune", f"{self.run_dir}: old log segments not pruned: {exc}")
            return
        if 0 < self.max_bytes < size:
            self._warn.warn("bound", (
                f"{self.run_dir}: the episode log holds {size:,} bytes, above replay."
                f"log_max_bytes={self.max_bytes:,}: its oldest segment still holds episodes "
                "the buffer holds, which resume needs (raise the bound, or set it to 0 to "
                "keep only what resume needs)"))

    def _usable_writer(self) -> EpisodeLogWriter:
        if self._closed:
            raise EpisodeLogError(f"{self.run_dir}: append after close(); nothing was written")
        if self._failed_since is None and self._writer is not None:
            return self._writer
        now = self._clock()
        if now < self._next_try:
            raise EpisodeLogError(
                f"{self.run_dir}: the episode log cannot be written since "
                f"{now - (self._failed_since or now):.1f} s ({self._error}); nothing was "
                f"written, a new segment is tried every {self.retry_s:g} s")
        self._next_try = now + self.retry_s
        old, self._writer = self._writer, None
        self.flush_upkeep()  # no writer of ours may still be closing a numbered segment
        try:
            if old is not None:
                was_failed = old.failed
                old.close()  # a failed writer closes without writing
                if was_failed and old.durable_end > 0:
                    # the failed append's bytes, complete or not, were never acked: cut them,
                    # so the id the caller gives the next episode is not in the log already
                    os.truncate(old.path, old.durable_end)
            sealed = EpisodeLog.retire(self.run_dir, run=self.run, task=self.task)
            writer = EpisodeLogWriter(EpisodeLog(self.run_dir).live_path, run=self.run,
                                      task=self.task, start_time_ns=run_start_ns(sealed),
                                      scene=self.scene, spec=self.spec)
        except OSError as exc:
            self._fail(exc)
            raise EpisodeLogError(f"{self.run_dir}: cannot start a new log segment ({exc}); "
                                  "nothing was written") from None
        down = now - (self._failed_since or now)
        log.warning("%s: episode log writable again after %.1f s; continuing in a new segment",
                    self.run_dir, down)
        self._writer, self._failed_since, self._error = writer, None, ""
        self.recoveries += 1
        return writer

    def _fail(self, exc: BaseException) -> None:
        now = self._clock()
        if self._failed_since is None:
            self._failed_since = now
            self._next_try = now + self.retry_s
            log.error("%s: episode log write failed (%s); inserts are refused until a new "
                      "segment can be started (tried every %g s)", self.run_dir, exc,
                      self.retry_s)
        self._error = f"{type(exc).__name__}: {exc}"
