"""The served batch: what one sample call hands from the replay to the learner, as one Python
type with one field list shared with its wire message, and its one encode/decode pair.

A batch carries what describes its own draw. The replay's standing counters (`ReplayCounters`,
`ReplayStatus` field for field: a test holds them equal) travel on a channel of their own:
`replay/status`, put about once a second, and `replay/status_at`, which answers a
`ReplayStatusRequest` with the counters as they stood when the batch that ended at
`samples_served` was drawn. An epoch's metrics row is read that way, so two lockstep runs with
one seed write the same numbers whatever their timing.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.proto.schema import MAX_BATCH_BYTES, SCHEMA_VERSION
from hercs.reasons import Reason
from hercs.rl.normalizer import NormalizerState, checked_state
from hercs.rl.task_registry import TaskSpec
from hercs.wire.batch import TransitionBatch
from hercs.wire.codec import batch_to_bytes, msg_to_stats, stats_to_msg
from hercs.wire.validation import MAX_INT64, decode_minibatch, parse_message


@dataclass(frozen=True)
class ReplayCounters:
    """The replay's counters at one moment (`ReplayStatus`, field for field)."""

    size_episodes: int = 0
    size_transitions: int = 0
    inserts: int = 0
    """Episodes inserted so far (duplicates not counted)."""
    duplicates: int = 0
    samples: int = 0
    """Minibatches served."""
    rate_limiter: str = ""
    """A short word for the limiter's state: ok, holding-samples, holding-inserts, free-run,
    lockstep."""
    rejects: dict[str, int] = field(default_factory=dict)
    """Refused messages by reason."""
    cluster_sizes: list[int] = field(default_factory=list)
    cluster_model_version: int = 0
    env_steps: int = 0
    policy_lag: float = 0.0
    """Mean over recent episodes of (their cycle in the lockstep schedule) − (the weights
    version they were acted with): 0 in lockstep."""
    policy_lag_request: float = 0.0
    """Mean over recent episodes of (the version of the learner's latest sample request when
    they were stored) − (the version they were acted with)."""
    buffer_moved_share: float = 0.0
    """Share of the stored episodes whose achieved goal moved."""
    inserts_waiting: int = 0
    samples_waiting: int = 0


COUNTER_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(ReplayCounters))


@dataclass(frozen=True)
class ServedBatch:
    """One sample call's answer: the minibatches and what the learner adopts and reports with
    them (`Batch` minus its envelope: schema_version, request_id)."""

    minibatches: list[TransitionBatch]
    o_stats: NormalizerState
    g_stats: NormalizerState
    cluster_draws: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """(k,) episodes drawn per cluster over all minibatches (zeros for the methods without
    clusters, or before any model)."""
    policy_lags: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """The lag (as `ReplayCounters.policy_lag`) of each episode stored since the previous
    sample call, so that the learner reports the distribution over an epoch's episodes."""
    sampled_moved: int = 0
    """Transitions of this batch whose episode's achieved goal moved."""
    sampled_transitions: int = 0
    samples_served: int = 0
    """The replay's `samples` (minibatches served) once this batch was drawn: what the learner
    asks `replay/status_at` for to read the counters of that moment."""
    buffer_moved_share: float = 0.0
    """Share of the stored episodes whose achieved goal moved, when this batch was drawn (what
    `sampled_moved / sampled_transitions` is set against)."""


BATCH_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(ServedBatch))


def counters_to_msg(counters: ReplayCounters) -> pb.ReplayStatus:
    return pb.ReplayStatus(schema_version=SCHEMA_VERSION, **dataclasses.asdict(counters))


def msg_to_counters(msg: pb.ReplayStatus) -> ReplayCounters:
    """Counters as sent; a non-finite mean reads as 0 (it is only reported)."""
    values = {name: getattr(msg, name) for name in COUNTER_FIELDS}
    values["rejects"] = dict(msg.rejects)
    values["cluster_sizes"] = [int(c) for c in msg.cluster_sizes]
    for name in ("policy_lag", "policy_lag_request", "buffer_moved_share"):
        values[name] = float(values[name]) if math.isfinite(values[name]) else 0.0
    return ReplayCounters(**values)


def served_batch_to_bytes(batch: ServedBatch, *, request_id: int) -> bytes:
    """The `Batch` reply to request `request_id` (minibatches joined fast: `batch_to_bytes`)."""
    header = pb.Batch(
        schema_version=SCHEMA_VERSION, request_id=request_id,
        o_stats=stats_to_msg(batch.o_stats), g_stats=stats_to_msg(batch.g_stats),
        cluster_draws=[int(c) for c in batch.cluster_draws],
        policy_lags=[int(lag) for lag in batch.policy_lags],
        sampled_moved=batch.sampled_moved, sampled_transitions=batch.sampled_transitions,
        samples_served=batch.samples_served, buffer_moved_share=batch.buffer_moved_share)
    return batch_to_bytes(header, batch.minibatches)


def decode_served_batch(raw: bytes, *, spec: TaskSpec, k: int, batch_size: int,
                        num_minibatches: int) -> ServedBatch:
    """A `Batch` reply checked before any update sees it: the minibatches asked for, each of
    the task's shapes, float32 and finite (`decode_minibatch`), normaliser statistics that a
    normaliser of the task's sizes accepts, and `k` cluster draws (or none). Raises
    `InvalidMessage` naming what is wrong."""
    msg = parse_message(raw, pb.Batch, max_bytes=MAX_BATCH_BYTES)
    if len(msg.minibatches) != num_minibatches:
        raise InvalidMessage(Reason.BAD_LENGTH,
                             f"Batch: {len(msg.minibatches)} minibatches, asked for "
                             f"{num_minibatches}")
    minibatches = [decode_minibatch(mb, spec, batch_size=batch_size,
                                    where=f"Batch.minibatches[{i}]")
                   for i, mb in enumerate(msg.minibatches)]
    o_stats = msg_to_stats(msg.o_stats, where="Batch.o_stats")
    g_stats = msg_to_stats(msg.g_stats, where="Batch.g_stats")
    for stats, size, where in ((o_stats, spec.obs_dim, "Batch.o_stats"),
                               (g_stats, spec.goal_dim, "Batch.g_stats")):
        try:
            checked_state(stats, size)
        except ValueError as exc:
            raise InvalidMessage(Reason.BAD_VALUE, f"{where}: {exc}") from None
    if len(msg.cluster_draws) not in (0, k):
        raise InvalidMessage(Reason.BAD_LENGTH,
                             f"Batch.cluster_draws: {len(msg.cluster_draws)} values, expected "
                             f"{k} (cluster.k) or none")
    if msg.sampled_moved > msg.sampled_transitions:
        raise InvalidMessage(Reason.BAD_VALUE,
                             f"Batch.sampled_moved {msg.sampled_moved} exceeds "
                             f"Batch.sampled_transitions {msg.sampled_transitions}")
    share = checked_share(msg.buffer_moved_share, where="Batch.buffer_moved_share")
    if any(d > MAX_INT64 for d in msg.cluster_draws):  # they are summed in an int64 array
        raise InvalidMessage(Reason.BAD_VALUE,
                             f"Batch.cluster_draws: {list(msg.cluster_draws)} holds a value "
                             f"above {MAX_INT64}")
    return ServedBatch(
        minibatches=minibatches, o_stats=o_stats, g_stats=g_stats,
        cluster_draws=np.asarray(msg.cluster_draws, np.int64),
        policy_lags=np.asarray(msg.policy_lags, np.int64),
        sampled_moved=int(msg.sampled_moved), sampled_transitions=int(msg.sampled_transitions),
        samples_served=int(msg.samples_served), buffer_moved_share=float(share))


def status_request(samples: int) -> bytes:
    """The `replay/status_at` query for the counters once `samples` minibatches were served."""
    return pb.ReplayStatusRequest(schema_version=SCHEMA_VERSION,
                                  samples=samples).SerializeToString()


def decode_status(raw: bytes, *, max_bytes: int) -> ReplayCounters:
    """A `ReplayStatus` reply, checked: a moved share that is not a share in [0, 1] raises
    `InvalidMessage` naming it, as it did when these counters rode in the `Batch`."""
    msg = parse_message(raw, pb.ReplayStatus, max_bytes=max_bytes)
    checked_share(msg.buffer_moved_share, where="ReplayStatus.buffer_moved_share")
    return msg_to_counters(msg)


def checked_share(share: float, *, where: str) -> float:
    """`share` if it is a share in [0, 1] (NaN is not), else `InvalidMessage` naming `where`."""
    if not 0.0 <= share <= 1.0:
        raise InvalidMessage(Reason.BAD_VALUE, f"{where} {share!r} is not a share in [0, 1]")
    return share

