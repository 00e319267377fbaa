"""Validation of messages from the wire. A rejected message never reaches a buffer, the
clusterer or the learner; the reason is counted in `ReplayStatus.rejects` and sent back in
the error reply.

Every check raises `InvalidMessage(reason, detail)`: a `hercs.reasons.Reason` and a detail
saying what and where; `decode_episode` goes from raw bytes to a checked `EpisodeData`.
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np
from google.protobuf.message import DecodeError, Message

from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.proto.schema import SCHEMA_VERSION
from hercs.reasons import Reason
from hercs.rl.task_registry import TaskSpec
from hercs.wire.batch import TRANSITION_FIELDS, CheckedBatch, TransitionBatch, transition_shapes
from hercs.wire.codec import msg_to_array, msg_to_episode
from hercs.wire.episode import EpisodeData, expected_shapes

M = TypeVar("M", bound=Message)

MAX_INT64 = 2**63 - 1
"""Counters that travel as uint64 but are kept as int64 (numpy arrays, int64 message fields)
must not exceed this."""


def parse_message(raw: bytes, cls: type[M], *, max_bytes: int) -> M:
    """Parse bytes into `cls`, checking size and schema version first."""
    name = cls.DESCRIPTOR.name
    if len(raw) > max_bytes:
        raise InvalidMessage(Reason.OVERSIZED,
                             f"{name}: {len(raw)} bytes exceeds the limit of {max_bytes}")
    msg = cls()
    try:
        msg.ParseFromString(bytes(raw))
    except (DecodeError, ValueError, RuntimeError) as exc:
        raise InvalidMessage(Reason.UNDECODABLE,
                             f"{name}: {len(raw)} bytes do not parse ({exc})") from None
    version = getattr(msg, "schema_version", SCHEMA_VERSION)
    if version != SCHEMA_VERSION:
        raise InvalidMessage(
            Reason.SCHEMA_VERSION,
            f"{name}: schema_version {version}, this process speaks {SCHEMA_VERSION}"
            + (" (0 usually means the bytes are not a hercs message)" if version == 0 else ""),
        )
    return msg


def _check_array(where: str, msg: pb.Array, shape: tuple[int, ...],
                 length_axis: bool) -> np.ndarray:
    """`msg`'s values (a read-only view of its bytes) if they are a float32 array of exactly
    `shape`, all finite; else `InvalidMessage` saying why. `length_axis`: a mismatch only in
    the first axis is `bad_length`."""
    if not msg.dtype and not msg.data and not msg.shape:
        raise InvalidMessage(Reason.MISSING_FIELD, f"{where} is missing")
    if msg.dtype != "float32":
        raise InvalidMessage(Reason.BAD_DTYPE, f"{where}: dtype {msg.dtype!r}, expected float32")
    got = tuple(int(d) for d in msg.shape)
    if got != shape:
        if length_axis and len(got) == len(shape) and got[1:] == shape[1:]:
            raise InvalidMessage(Reason.BAD_LENGTH,
                                 f"{where}: {got[0]} steps, the task's episodes have {shape[0]}")
        raise InvalidMessage(Reason.BAD_SHAPE, f"{where}: shape {got}, expected {shape}")
    values = msg_to_array(msg, where=where)
    finite = np.isfinite(values)
    if not finite.all():
        index = tuple(int(i) for i in np.argwhere(~finite)[0])
        raise InvalidMessage(Reason.NON_FINITE,
                             f"{where}: non-finite value {values[index]!r} at index {index}")
    return values


def validate_episode(
    msg: pb.Episode, spec: TaskSpec, *, run: str | None = None
) -> None:
    """Check a parsed Episode against the task; None if it may be stored."""
    if msg.schema_version != SCHEMA_VERSION:
        raise InvalidMessage(Reason.SCHEMA_VERSION,
                             f"Episode: schema_version {msg.schema_version}, expected "
                             f"{SCHEMA_VERSION}")
    if run is not None and msg.run != run:
        raise InvalidMessage(Reason.UNKNOWN_RUN,
                             f"Episode.run {msg.run!r}: this replay serves run {run!r}")
    if msg.task != spec.name:
        raise InvalidMessage(Reason.WRONG_TASK,
                             f"Episode.task {msg.task!r}: this replay serves task {spec.name!r}")
    if not msg.actor_id:
        raise InvalidMessage(Reason.MISSING_FIELD, "Episode.actor_id is empty")
    if msg.seq > MAX_INT64:  # the store keeps seq in an int64 array
        raise InvalidMessage(Reason.BAD_VALUE,
                             f"Episode.seq {msg.seq} is above {MAX_INT64} (2**63 - 1)")
    for field, shape in expected_shapes(spec).items():
        _check_array(f"Episode.{field}", getattr(msg, field), shape, length_axis=True)


def decode_episode(raw: bytes, spec: TaskSpec, *, run: str | None,
                   max_bytes: int) -> tuple[pb.Episode, EpisodeData]:
    """Raw bytes from `replay/insert` to the message (what the log keeps) and a checked
    episode, or `InvalidMessage`."""
    msg = parse_message(raw, pb.Episode, max_bytes=max_bytes)
    validate_episode(msg, spec, run=run)
    return msg, msg_to_episode(msg)


def validate_sample_request(msg: pb.SampleRequest, *, run: str | None,
                            max_minibatches: int, max_batch_size: int,
                            max_rows: int | None = None) -> None:
    """A request the replay may serve; `max_rows` bounds minibatches × batch size, i.e. the
    reply's size (each row is a few hundred bytes)."""
    if run is not None and msg.run != run:
        raise InvalidMessage(Reason.UNKNOWN_RUN,
                             f"SampleRequest.run {msg.run!r}: this replay serves run {run!r}")
    if not 1 <= msg.num_minibatches <= max_minibatches:
        raise InvalidMessage(Reason.BAD_VALUE,
                             f"SampleRequest.num_minibatches {msg.num_minibatches}, "
                             f"must be in [1, {max_minibatches}]")
    if not 1 <= msg.batch_size <= max_batch_size:
        raise InvalidMessage(Reason.BAD_VALUE,
                             f"SampleRequest.batch_size {msg.batch_size}, "
                             f"must be in [1, {max_batch_size}]")
    rows = msg.num_minibatches * msg.batch_size
    if max_rows is not None and rows > max_rows:
        raise InvalidMessage(Reason.BAD_VALUE,
                             f"SampleRequest of {msg.num_minibatches} minibatches × "
                             f"{msg.batch_size} rows = {rows} rows, above the {max_rows} one reply "
                             "may hold; ask for fewer minibatches per request")


def decode_minibatch(msg: pb.Minibatch, spec: TaskSpec, *, batch_size: int,
                     where: str = "Minibatch") -> TransitionBatch:
    """A `Minibatch` as the learner takes it: every field float32 of the task's shape with
    `batch_size` rows, all finite; else `InvalidMessage` naming the field."""
    shapes = transition_shapes(spec, batch_size)
    return CheckedBatch(*(_check_array(f"{where}.{name}", getattr(msg, name), shapes[name],
                                       length_axis=False) for name in TRANSITION_FIELDS))


def validate_centroids(msg: pb.ClusterModel, *, k: int, goal_dim: int = 3) -> None:
    """Check a ClusterModel before the replay relabels its episodes with it."""
    centroids = msg_to_array(msg.centroids, where="ClusterModel.centroids")
    if centroids.shape != (k, goal_dim):
        raise InvalidMessage(Reason.BAD_SHAPE,
                             f"ClusterModel.centroids: shape {centroids.shape}, "
                             f"expected {(k, goal_dim)}")
    if not np.isfinite(centroids).all():
        raise InvalidMessage(Reason.NON_FINITE, "ClusterModel.centroids: non-finite values")


def validate_eval_result(msg: pb.EvalResult) -> None:
    """Check an `EvalResult` before it is logged or recorded: at least one episode, a finite
    success rate in [0, 1] and a finite, non-negative mean final distance."""
    if msg.episodes < 1:
        raise InvalidMessage(Reason.BAD_VALUE,
                             f"EvalResult.episodes {msg.episodes}, must be >= 1")
    for name in ("success_rate", "mean_final_distance"):
        if not math.isfinite(getattr(msg, name)):
            raise InvalidMessage(Reason.NON_FINITE,
                                 f"EvalResult.{name} {getattr(msg, name)!r} is not finite")
    if not 0.0 <= msg.success_rate <= 1.0:
        raise InvalidMessage(Reason.BAD_VALUE,
                             f"EvalResult.success_rate {msg.success_rate!r}, must be in [0, 1]")
    if msg.mean_final_distance < 0.0:
        raise InvalidMessage(Reason.BAD_VALUE, f"EvalResult.mean_final_distance "
                                               f"{msg.mean_final_distance!r}, must be >= 0")


def header_goals(msg: pb.EpisodeHeader, *, goal_dim: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(final achieved goal, desired goal) of an `EpisodeHeader`, float64 (goal_dim,) each.

    Raises `InvalidMessage` for a missing or misshapen vector, or NaN/Inf; the detail names
    the field.
    """
    out = []
    for field in ("final_achieved_goal", "desired_goal"):
        where = f"EpisodeHeader.{field}"
        if not msg.HasField(field):
            raise InvalidMessage(Reason.MISSING_FIELD, f"{where} is missing")
        value = msg_to_array(getattr(msg, field), where=where)
        if value.shape != (goal_dim,):
            raise InvalidMessage(Reason.BAD_SHAPE,
                                 f"{where}: shape {value.shape}, expected ({goal_dim},)")
        if not np.all(np.isfinite(value)):
            raise InvalidMessage(Reason.NON_FINITE, f"{where}: non-finite {value!r}")
        out.append(value.astype(np.float64))
    return out[0], out[1]
