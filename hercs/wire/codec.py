"""numpy ⇄ message conversion. Arrays travel as {dtype, shape, raw little-endian bytes}.

Decoding is strict: a dtype outside `WIRE_DTYPES`, a negative dimension or a byte count that
does not match the shape raises `InvalidMessage` naming the field, so a malformed array never
becomes a numpy array.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.proto.schema import SCHEMA_VERSION
from hercs.reasons import Reason
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.normalizer import NormalizerState
from hercs.wire import pbwire
from hercs.wire.batch import TRANSITION_FIELDS, TransitionBatch
from hercs.wire.episode import EpisodeData
from hercs.wire.replay_state import ReplayState

WIRE_DTYPES = frozenset({"float32", "float64", "int32", "int64", "uint8", "bool"})
MAX_NDIM = 8
MAX_DIM = 2**31 - 1
"""Bounds on a wire array's shape; nothing this project sends comes near them."""



def array_to_msg(value: np.ndarray, out: pb.Array | None = None) -> pb.Array:
    """Encode an array as C-order little-endian bytes (copies only if needed)."""
    arr = np.asarray(value)
    if arr.dtype.name not in WIRE_DTYPES:
        raise TypeError(f"array dtype {arr.dtype} cannot travel; use one of {sorted(WIRE_DTYPES)}")
    arr = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<"))
    msg = out if out is not None else pb.Array()
    msg.dtype = arr.dtype.name
    msg.shape[:] = arr.shape
    msg.data = arr.tobytes()
    return msg


def msg_to_array(msg: pb.Array, *, where: str = "array") -> np.ndarray:
    """Decode an Array message; the result is a read-only view of the message bytes."""
    if msg.dtype not in WIRE_DTYPES:
        raise InvalidMessage(
            Reason.BAD_DTYPE, f"{where}: dtype {msg.dtype!r} is not one of {sorted(WIRE_DTYPES)}"
        )
    shape = tuple(int(d) for d in msg.shape)
    if len(shape) > MAX_NDIM:
        raise InvalidMessage(Reason.BAD_ARRAY,
                             f"{where}: {len(shape)} dimensions, at most {MAX_NDIM}")
    if any(d < 0 for d in shape):
        raise InvalidMessage(Reason.BAD_ARRAY, f"{where}: negative dimension in shape {shape}")
    if any(d > MAX_DIM for d in shape):
        raise InvalidMessage(Reason.BAD_ARRAY,
                             f"{where}: dimension above {MAX_DIM} in shape {shape}")
    dtype = np.dtype(msg.dtype).newbyteorder("<")
    # Python integers: a product of wire dimensions cannot wrap around (np.prod would).
    expected = math.prod(shape) * dtype.itemsize
    if len(msg.data) != expected:
        raise InvalidMessage(
            Reason.BAD_ARRAY,
            f"{where}: {len(msg.data)} data bytes for shape {shape} {msg.dtype}, "
            f"expected {expected}",
        )
    try:
        flat = np.frombuffer(msg.data, dtype=dtype).reshape(shape)
    except ValueError as exc:  # e.g. an empty array whose other dimensions overflow numpy
        raise InvalidMessage(Reason.BAD_ARRAY, f"{where}: shape {shape} is not an array numpy can "
                                        f"hold ({exc})") from None
    return flat.astype(dtype.newbyteorder("="), copy=False)


def arrays_to_named(params: Mapping[str, np.ndarray]) -> list[pb.NamedArray]:
    return [pb.NamedArray(name=name, array=array_to_msg(value)) for name, value in params.items()]


def named_to_arrays(items: Iterable[pb.NamedArray], *, where: str) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for item in items:
        if item.name in out:
            raise InvalidMessage(Reason.BAD_ARRAY, f"{where}: duplicate array name {item.name!r}")
        out[item.name] = msg_to_array(item.array, where=f"{where}[{item.name}]")
    return out


def episode_to_msg(episode: EpisodeData, *, run: str, task: str) -> pb.Episode:
    return pb.Episode(
        schema_version=SCHEMA_VERSION,
        run=run,
        actor_id=episode.actor_id,
        seq=episode.seq,
        task=task,
        obs=array_to_msg(episode.obs.astype(np.float32, copy=False)),
        ag=array_to_msg(episode.ag.astype(np.float32, copy=False)),
        g=array_to_msg(episode.g.astype(np.float32, copy=False)),
        actions=array_to_msg(episode.actions.astype(np.float32, copy=False)),
        success=bool(episode.success),
        policy_version=int(episode.policy_version),
    )


def msg_to_episode(msg: pb.Episode) -> EpisodeData:
    """Convert without checking shapes against a task; use validation.decode_episode on input
    from the wire."""
    return EpisodeData(
        obs=msg_to_array(msg.obs, where="Episode.obs"),
        ag=msg_to_array(msg.ag, where="Episode.ag"),
        g=msg_to_array(msg.g, where="Episode.g"),
        actions=msg_to_array(msg.actions, where="Episode.actions"),
        actor_id=msg.actor_id,
        seq=int(msg.seq),
        success=bool(msg.success),
        policy_version=int(msg.policy_version),
    )


def cluster_model_to_msg(model: ClusterModel) -> pb.ClusterModel:
    """The clusterer's model as published on `cluster/model` and logged by the replay."""
    return pb.ClusterModel(schema_version=SCHEMA_VERSION, version=model.version,
                           centroids=array_to_msg(model.centroids), fitted_on=model.n_goals,
                           failures_seen=model.failures_seen)


def msg_to_cluster_model(msg: pb.ClusterModel) -> ClusterModel:
    """The one reading of a `ClusterModel` message (replay, live view, `hercs view`, benches).

    Field 5 was named `failed_goals_seen` in logs written before; the number is the same, so
    they decode here unchanged. Raises `InvalidMessage` for an undecodable array, a version
    below 1 or non-finite centroids; the shape against k and goal_dim is the caller's check
    (`validation.validate_centroids`)."""
    centroids = msg_to_array(msg.centroids, where="ClusterModel.centroids").copy()
    try:
        return ClusterModel(version=int(msg.version), centroids=centroids,
                            n_goals=int(msg.fitted_on), failures_seen=int(msg.failures_seen))
    except ValueError as exc:
        raise InvalidMessage(Reason.BAD_VALUE, str(exc)) from None


NORMALIZER_ARRAYS = ("sum", "sumsq", "mean", "std")


def stats_to_msg(state: Mapping[str, np.ndarray | float]) -> pb.NormalizerStats:
    """Encode a normaliser state dict {sum, sumsq, count, mean, std}."""
    msg = pb.NormalizerStats(count=float(state["count"]))
    for name in NORMALIZER_ARRAYS:
        array_to_msg(np.asarray(state[name]), out=getattr(msg, name))
    return msg


def msg_to_stats(msg: pb.NormalizerStats, *, where: str) -> NormalizerState:
    state: NormalizerState = {"count": float(msg.count)}
    for name in NORMALIZER_ARRAYS:
        state[name] = msg_to_array(getattr(msg, name), where=f"{where}.{name}")
    return state


def minibatch_to_msg(batch: TransitionBatch) -> pb.Minibatch:
    msg = pb.Minibatch()
    for name, value in zip(TRANSITION_FIELDS, batch, strict=True):
        array_to_msg(np.asarray(value, dtype=np.float32), out=getattr(msg, name))
    return msg


_MINIBATCHES_TAG = pbwire.field_key(pb.Batch.DESCRIPTOR, "minibatches", pbwire.LENGTH_DELIMITED)
"""Field key of `Batch.minibatches` (wire type 2, length-delimited)."""


def batch_to_bytes(header: pb.Batch, minibatches: Sequence[TransitionBatch]) -> bytes:
    """The serialised `Batch` = `header` with `minibatches` as its repeated `minibatches`.

    The same message as setting `header.minibatches` and calling `SerializeToString()`
    (protobuf parses a repeated field from entries anywhere in the message), about 4× faster
    for a 40×256 FetchPush reply (~2.4 MB: 1.2 ms against 4.9 ms): upb serialises one large
    message into a buffer it grows and copies, while 40 minibatches of ~60 kB each serialise
    without that, and joining them costs one copy. This is on the replay's sampling path."""
    if len(header.minibatches):
        raise ValueError("batch_to_bytes: the header must not hold minibatches already")
    parts = [header.SerializeToString()]
    for batch in minibatches:
        body = minibatch_to_msg(batch).SerializeToString()
        parts += [_MINIBATCHES_TAG, pbwire.varint(len(body)), body]
    return b"".join(parts)


def weights_to_msg(*, version: int, actor_params: Mapping[str, np.ndarray],
                   o_stats: Mapping[str, np.ndarray | float],
                   g_stats: Mapping[str, np.ndarray | float], epoch: int,
                   evaluate: bool) -> pb.Weights:
    """The learner's broadcast: actor parameters plus the normaliser stats it trained with."""
    return pb.Weights(schema_version=SCHEMA_VERSION, version=version,
                      actor_params=arrays_to_named(actor_params),
                      o_stats=stats_to_msg(o_stats), g_stats=stats_to_msg(g_stats),
                      epoch=epoch, evaluate=evaluate)


def msg_to_weight_arrays(
    msg: pb.Weights,
) -> tuple[dict[str, np.ndarray], NormalizerState, NormalizerState]:
    """(actor params, o stats, g stats) of a Weights message; names and shapes are checked by
    whoever loads them into a network."""
    return (named_to_arrays(msg.actor_params, where="Weights.actor_params"),
            msg_to_stats(msg.o_stats, where="Weights.o_stats"),
            msg_to_stats(msg.g_stats, where="Weights.g_stats"))


def replay_state_to_msg(state: ReplayState) -> pb.ReplayState:
    """The replay's state as its log keeps it (`/replay_state`)."""
    versions = sorted(state.stored_per_version.items())
    msg = pb.ReplayState(
        schema_version=SCHEMA_VERSION, next_episode_id=state.next_episode_id,
        first_held_id=state.first_held_id, failures=state.failures,
        recent_failed_goals=array_to_msg(np.asarray(state.recent_failed_goals, np.float32)),
        o_stats=stats_to_msg(state.o_stats), g_stats=stats_to_msg(state.g_stats),
        lockstep_versions=[v for v, _ in versions], lockstep_counts=[n for _, n in versions])
    if state.cluster_model is not None:
        msg.cluster_model.CopyFrom(cluster_model_to_msg(state.cluster_model))
    return msg


def msg_to_replay_state(msg: pb.ReplayState) -> ReplayState:
    """Raises `InvalidMessage` for an undecodable array or model, or counts that disagree."""
    if len(msg.lockstep_versions) != len(msg.lockstep_counts):
        raise InvalidMessage(Reason.BAD_VALUE, f"ReplayState: {len(msg.lockstep_versions)} "
                             f"lockstep versions but {len(msg.lockstep_counts)} counts")
    try:
        return ReplayState(
            next_episode_id=int(msg.next_episode_id), first_held_id=int(msg.first_held_id),
            failures=int(msg.failures),
            recent_failed_goals=msg_to_array(msg.recent_failed_goals,
                                             where="ReplayState.recent_failed_goals").copy(),
            o_stats=msg_to_stats(msg.o_stats, where="ReplayState.o_stats"),
            g_stats=msg_to_stats(msg.g_stats, where="ReplayState.g_stats"),
            cluster_model=(msg_to_cluster_model(msg.cluster_model)
                           if msg.HasField("cluster_model") else None),
            stored_per_version=dict(zip((int(v) for v in msg.lockstep_versions),
                                        (int(n) for n in msg.lockstep_counts), strict=True)))
    except ValueError as exc:
        raise InvalidMessage(Reason.BAD_VALUE, str(exc)) from None
