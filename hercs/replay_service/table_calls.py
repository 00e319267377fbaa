"""What the replay table (hercs.replay_service.table) is called with and answers: inserts and
sample calls, the waiters that get each answer (now or once the rate limiter admits it), a
parked call, and the sink the episode log is."""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

import numpy as np

from hercs.errors import HercsError
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.run.runlog.format import EpisodeLogError
from hercs.wire.codec import replay_state_to_msg
from hercs.wire.episode import EpisodeData
from hercs.wire.replay_state import ReplayState
from hercs.wire.served import ServedBatch

log = logging.getLogger("hercs.replay")

T_contra = TypeVar("T_contra", contravariant=True)
T = TypeVar("T")


class Waiter(Protocol[T_contra]):
    """How the table answers one call, now or later, exactly once."""

    def done(self, result: T_contra) -> None: ...

    def fail(self, reason: Reason, detail: str) -> None: ...


class EpisodeLogSink(Protocol):
    """The durable log the table writes before it acknowledges (hercs.run.runlog's writer)."""

    def append_many(self, episodes: list[tuple[int, pb.Episode]]) -> None: ...

    def append_cluster_model(self, msg: pb.ClusterModel) -> None: ...

    def append_eval_result(self, msg: pb.EvalResult) -> None: ...

    def rotation_due(self) -> bool:
        """A bounded log has logged a segment's episodes since its newest replay state: the
        table should `start_segment`."""
        ...

    def start_segment(self, state: pb.ReplayState) -> None:
        """Start the next segment with the replay's state (no episode is logged meanwhile)."""
        ...


class NoLog:
    """The log of an in-process table (a bench's, a study's, a test's): nothing is written."""

    def append_many(self, episodes: list[tuple[int, pb.Episode]]) -> None:
        pass

    def append_cluster_model(self, msg: pb.ClusterModel) -> None:
        pass

    def append_eval_result(self, msg: pb.EvalResult) -> None:
        pass

    def rotation_due(self) -> bool:
        return False

    def start_segment(self, state: pb.ReplayState) -> None:
        pass


def start_segment(sink: EpisodeLogSink, state: ReplayState) -> None:
    """Start a bounded log's next segment with `state`; a failure is logged, and leaves the
    log as after a failed append (the next one retries) or as it was."""
    try:
        sink.start_segment(replay_state_to_msg(state))
    except (EpisodeLogError, ValueError) as exc:
        log.warning("episode log: no new segment at episode %d (%s)", state.next_episode_id,
                    exc)


@dataclass(frozen=True)
class Stored:
    """The answer to an insert."""

    episode: EpisodeData
    episode_id: int
    duplicate: bool
    energy: float = 0.0
    cluster: int = -1
    next_policy_version: int = 0
    """Lockstep: the oldest weights version the actor's next episode may be acted with (0
    otherwise)."""


@dataclass(frozen=True)
class SampleCall:
    """A learner's request, decoded."""

    num_minibatches: int
    batch_size: int
    weights_version: int = 0
    request_id: int = 0
    samples_kept: int = 0
    """Minibatches the learner's run has received and kept (SampleRequest.samples_kept)."""
    learner_incarnation: str = ""
    """The learner process ('' from a learner that does not say: never resynced)."""


class SampleRefused(ValueError):
    """A sample call the rate limiter could never admit; nothing was parked."""


class EpisodeIdConflict(HercsError):
    """An admitted insert the store already holds: logging it would record an id the store
    does not give it. Found before the log is written; the calls are answered, not stored."""


@dataclass
class Parked(Generic[T]):
    waiters: list[Waiter[T]]
    deadline: float | None


@dataclass
class ParkedInsert(Parked[Stored]):
    episode: EpisodeData = field(kw_only=True)
    record: pb.Episode = field(kw_only=True)


@dataclass
class ParkedSample(Parked[ServedBatch]):
    call: SampleCall = field(kw_only=True)


P = TypeVar("P", bound=Parked)


def take_expired(queue: deque[P], now: float) -> list[P]:
    """Remove and return the calls past their deadline; the others keep their order."""
    gone = [item for item in queue if item.deadline is not None and item.deadline <= now]
    if gone:
        keep = [item for item in queue if item.deadline is None or item.deadline > now]
        queue.clear()
        queue.extend(keep)
    return gone


@dataclass(frozen=True)
class ClustererSnapshot:
    failed_goals: np.ndarray
    """(n, goal_dim) float32, n ≤ cluster.fgb_size, oldest first."""
    failures_seen: int
    episodes_seen: int
    model_version: int
