"""Probes (a payload, how it was made, the reason it must give), the generic strategies
(random, mutated, oversized, of another type), arrays with one thing wrong and the valid
messages the barrages start from."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.synthetic_episodes import random_episode
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.rl.normalizer import Normalizer
from hercs.rl.policy import Policy
from hercs.wire import pbwire
from hercs.wire.batch import TransitionBatch
from hercs.wire.codec import (
    array_to_msg,
    episode_to_msg,
    minibatch_to_msg,
    stats_to_msg,
    weights_to_msg,
)
from tests.fault.fuzz.runs import (
    ACTOR_CONFIG,
    HYPOTHESIS,
    LEARNER_B,
    LEARNER_N,
    RUN_R,
    SEEDS,
    SPEC,
    VALID,
    K,
)


@dataclass(frozen=True)
class Probe:
    payload: bytes
    kind: str
    """How it was made, e.g. "episode:array:obs:nonfinite" or "flip"."""
    expect: str | None
    """The reason its broken field must give (`VALID`: none); None: only the oracle knows."""

    def __repr__(self) -> str:
        head = self.payload[:24].hex()
        return f"Probe({self.kind}, expect={self.expect}, {len(self.payload)} B, {head}…)"

    def _repr_pretty_(self, printer: Any, cycle: bool) -> None:  # hypothesis's printer
        printer.text(repr(self))


def unknown_field(size: int) -> bytes:
    """A length-delimited protobuf field no hercs message defines (number 1000): parsers keep
    it as an unknown field, so a message padded with it still parses."""
    return pbwire.length_delimited(pbwire.varint(1000 << 3 | pbwire.LENGTH_DELIMITED),
                                   b"\xa5" * size)


MUTATIONS = ("truncate", "flip", "flips", "splice", "zero", "append", "duplicate")


def mutate(base: bytes, how: str, seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    data = bytearray(base)
    n = len(data)
    if how == "truncate":
        return bytes(data[: int(rng.integers(0, n))])
    if how in ("flip", "flips"):
        for _ in range(1 if how == "flip" else int(rng.integers(2, 33))):
            bit = int(rng.integers(0, 8 * n))
            data[bit // 8] ^= 1 << (bit % 8)
        return bytes(data)
    i, j = sorted(int(x) for x in rng.integers(0, n + 1, size=2))
    if how == "splice":
        return bytes(data[:i] + rng.bytes(int(rng.integers(0, 32))) + data[j:])
    if how == "zero":
        return bytes(data[:i] + bytes(j - i) + data[j:])
    if how == "append":
        return bytes(data + rng.bytes(int(rng.integers(1, 64))))
    return bytes(data + data[i:j])  # duplicate: repeated fields grow, scalars are overwritten


def random_probes() -> st.SearchStrategy[Probe]:
    return st.one_of(
        st.binary(max_size=48).map(lambda b: Probe(b, "random-bytes", None)),
        st.tuples(st.integers(0, 4096), SEEDS).map(
            lambda t: Probe(np.random.default_rng(t[1]).bytes(t[0]), "random-bytes", None)),
    )


def mutated_probes(bases: list[bytes]) -> st.SearchStrategy[Probe]:
    return st.tuples(st.sampled_from(bases), st.sampled_from(MUTATIONS), SEEDS).map(
        lambda t: Probe(mutate(t[0], t[1], t[2]), t[1], None))


def oversized_probes(bases: list[bytes], limit: int) -> st.SearchStrategy[Probe]:
    """Above `limit`: a valid message padded with an unknown field, or random bytes."""

    def make(t: tuple[bytes, int, bool, int]) -> Probe:
        base, extra, padded, seed = t
        if padded:
            payload = base + unknown_field(limit - len(base) + extra)
        else:
            payload = np.random.default_rng(seed).bytes(limit + extra)
        assert len(payload) > limit
        return Probe(payload, "oversized", Reason.OVERSIZED)

    return st.tuples(st.sampled_from(bases), st.integers(1, 4096), st.booleans(), SEEDS).map(
        make)


@st.composite
def mixed(draw: st.DrawFn, structured: st.SearchStrategy[Probe], bases: list[bytes],
          limit: int | None) -> Probe:
    """One probe: mostly a message with one field broken, else mutated, random, of another
    message type, or (if the receiver has a size limit worth testing) oversized."""
    options = ["structured"] * 9 + ["mutated"] * 5 + ["random"] * 3 + ["other-type"]
    if limit is not None:
        options.append("oversized")
    what = draw(st.sampled_from(options))
    if what == "structured":
        return draw(structured)
    if what == "mutated":
        return draw(mutated_probes(bases))
    if what == "random":
        return draw(random_probes())
    if what == "other-type":
        name, payload = draw(st.sampled_from(OTHER_MESSAGES))
        return Probe(payload, f"other-type:{name}", None)
    assert limit is not None
    return draw(oversized_probes(bases, limit))


def run_barrage(send: Callable[[list[Probe]], None], structured: st.SearchStrategy[Probe],
                bases: list[bytes], limit: int | None, *, examples: int) -> None:
    """Calls `send` once per Hypothesis example (`examples` of them, under the HYPOTHESIS
    settings every barrage shares) with 12 to 24 probes, each drawn by `mixed`."""
    probe_lists = st.lists(mixed(structured, bases, limit), min_size=12, max_size=24)
    settings(HYPOTHESIS, max_examples=examples)(given(probe_lists)(send))()


# ---- arrays with one thing wrong

ARRAY_KINDS = ("missing", "foreign_dtype", "wire_dtype", "length", "shape", "negative",
               "overflow", "ndim", "data", "nonfinite", "extreme")
FOREIGN_DTYPES = ("float16", "complex64", "", "<f4", "object", "float32 ", "FLOAT32", "U8")
OTHER_WIRE_DTYPES = ("float64", "int32", "int64", "uint8", "bool")


def break_array(value: np.ndarray, kind: str, rng: np.random.Generator) -> pb.Array:
    """`value` (float32) as an Array message with one thing wrong (`kind`); "missing" is an
    empty Array (callers that can clear the field do)."""
    value = np.asarray(value, np.float32)
    msg = array_to_msg(value)
    shape = list(value.shape)
    if kind == "missing":
        return pb.Array()
    if kind == "foreign_dtype":
        msg.dtype = str(rng.choice(FOREIGN_DTYPES))
    elif kind == "wire_dtype":
        array_to_msg(value.astype(str(rng.choice(OTHER_WIRE_DTYPES))), out=msg)
    elif kind == "length":  # only the first axis differs; bytes consistent with the shape
        n = shape[0] + int(rng.choice([-shape[0], -1, 1, 2, shape[0]]))
        array_to_msg(np.resize(value, (n, *shape[1:])).astype(np.float32), out=msg)
    elif kind == "shape":  # another rank or trailing axis; bytes consistent with the shape
        options = [(*shape, 1), (1, *shape)]
        if len(shape) >= 2:
            options += [(value.size,), (shape[0], shape[1] + 1, *shape[2:])]
        new = options[int(rng.integers(0, len(options)))]
        array_to_msg(np.resize(value, new).astype(np.float32), out=msg)
    elif kind == "negative":  # the first dimension negative
        msg.shape[0] = -int(rng.integers(1, 2**63 - 1))
    elif kind == "overflow":  # every dimension beyond 2**31: the product overflows int64
        msg.shape[:] = [int(rng.integers(2**31, 2**63 - 1)) for _ in shape]
    elif kind == "ndim":  # nine dimensions of 1 holding one value
        msg.shape[:] = [1] * 9
        msg.data = msg.data[:4]
    elif kind == "data":  # the byte count does not match the shape
        cut = int(rng.integers(1, 4 * max(value.size, 1) + 1))
        msg.data = msg.data[:-cut] if rng.random() < 0.5 else msg.data + rng.bytes(cut)
    elif kind == "nonfinite":
        flat = value.reshape(-1).copy()
        flat[int(rng.integers(0, flat.size))] = rng.choice([np.nan, np.inf, -np.inf])
        array_to_msg(flat.reshape(value.shape), out=msg)
    elif kind == "extreme":  # finite, but as large or small as float32 goes
        flat = value.reshape(-1).copy()
        picks = rng.integers(0, flat.size, size=max(1, flat.size // 4))
        flat[picks] = rng.choice(np.array([3.4e38, -3.4e38, 1e-45, -0.0], np.float32),
                                 size=picks.size)
        array_to_msg(flat.reshape(value.shape), out=msg)
    else:
        raise AssertionError(kind)
    return msg


# What each receiver says about an array broken that way (None: depends on the values).
EPISODE_ARRAY = {"missing": "missing_field", "foreign_dtype": "bad_dtype",
                 "wire_dtype": "bad_dtype", "length": "bad_length", "shape": "bad_shape",
                 "negative": "bad_length", "overflow": "bad_shape", "ndim": "bad_shape",
                 "data": "bad_array", "nonfinite": "non_finite", "extreme": VALID}
MINIBATCH_ARRAY = {**EPISODE_ARRAY, "length": "bad_shape", "negative": "bad_shape"}
CODEC_FIRST = {"missing": "bad_dtype", "foreign_dtype": "bad_dtype", "negative": "bad_array",
               "overflow": "bad_array", "ndim": "bad_array", "data": "bad_array"}
CENTROIDS_ARRAY = {**CODEC_FIRST, "wire_dtype": None, "length": "bad_shape",
                   "shape": "bad_shape", "nonfinite": "non_finite", "extreme": VALID}
HEADER_ARRAY = {**CENTROIDS_ARRAY, "missing": "missing_field", "wire_dtype": VALID}
LOADED_ARRAY = {**CODEC_FIRST, "wire_dtype": None, "length": "bad_value", "shape": "bad_value",
                "nonfinite": "bad_value", "extreme": None}
"""Weights parameters and normaliser statistics: the codec, then a scratch load."""


# ---- valid messages to start from

def base_episode(seed: int, *, actor: str = "fz-base") -> pb.Episode:
    episode = random_episode(SPEC, np.random.default_rng(seed), actor_id=actor, seq=seed)
    return episode_to_msg(episode, run=RUN_R, task=SPEC.name)


BASE_EPISODES = [base_episode(seed) for seed in range(6)]
"""Inserted when the replay starts (ids 0..5); mutations of them are mostly duplicates."""


def stats(dim: int, seed: int) -> dict[str, Any]:
    norm = Normalizer(dim)
    norm.update(np.random.default_rng(seed).standard_normal((20, dim)))
    norm.recompute_stats()
    return norm.state_dict()


def make_weights(*, version: int, epoch: int, evaluate: bool, seed: int = 0) -> pb.Weights:
    weights = Policy(spec=SPEC, config=ACTOR_CONFIG.ddpg, seed=seed).weights()
    return weights_to_msg(version=version, actor_params=weights.actor,
                          o_stats=stats(SPEC.obs_dim, seed), g_stats=stats(SPEC.goal_dim, seed),
                          epoch=epoch, evaluate=evaluate)


BASE_WEIGHTS = [make_weights(version=1000 + i, epoch=i, evaluate=i == 2, seed=i) for i in range(3)]


def make_batch(seed: int, *, n: int = LEARNER_N, b: int = LEARNER_B) -> pb.Batch:
    rng = np.random.default_rng(seed)

    def rows(dim: int) -> np.ndarray:
        return rng.standard_normal((b, dim)).astype(np.float32)

    minibatches = [minibatch_to_msg(TransitionBatch(
        o=rows(SPEC.obs_dim), g=rows(SPEC.goal_dim),
        u=rng.uniform(-1, 1, (b, SPEC.action_dim)).astype(np.float32),
        r=-(rng.random(b) < 0.5).astype(np.float32), o2=rows(SPEC.obs_dim))) for _ in range(n)]
    draws = rng.multinomial(n * b, [1 / K] * K)
    return pb.Batch(schema_version=SCHEMA_VERSION, request_id=seed, minibatches=minibatches,
                    o_stats=stats_to_msg(stats(SPEC.obs_dim, seed)),
                    g_stats=stats_to_msg(stats(SPEC.goal_dim, seed)),
                    cluster_draws=[int(d) for d in draws], samples_served=n * (seed + 1),
                    buffer_moved_share=0.25)


BASE_BATCHES = [make_batch(seed) for seed in range(3)]


def make_model(version: int, seed: int) -> pb.ClusterModel:
    centroids = np.random.default_rng(seed).uniform(-1, 1, (K, 3)).astype(np.float32)
    return pb.ClusterModel(schema_version=SCHEMA_VERSION, version=version,
                           centroids=array_to_msg(centroids), fitted_on=150,
                           failures_seen=150 + version)


FIRST_MODEL_VERSION = 3


def make_header(seed: int, episode_id: int | None = None) -> pb.EpisodeHeader:
    rng = np.random.default_rng(seed)
    return pb.EpisodeHeader(
        schema_version=SCHEMA_VERSION, episode_id=seed if episode_id is None else episode_id,
        actor_id="fz-header", seq=seed, success=False,
        final_achieved_goal=array_to_msg(rng.uniform(-1, 1, 3).astype(np.float32)),
        desired_goal=array_to_msg(rng.uniform(-1, 1, 3).astype(np.float32)),
        energy=0.1, cluster=-1, policy_version=-1)


def make_eval(epoch: int, version: int, *, success: float = 0.5,
              distance: float = 0.1, episodes: int = 2) -> pb.EvalResult:
    return pb.EvalResult(schema_version=SCHEMA_VERSION, epoch=epoch, weights_version=version,
                         episodes=episodes, success_rate=success,
                         mean_final_distance=distance)


OTHER_MESSAGES: list[tuple[str, bytes]] = [(type(m).__name__, m.SerializeToString()) for m in [
    BASE_EPISODES[0], BASE_WEIGHTS[0], BASE_BATCHES[0], make_model(1, 0), make_header(0),
    make_eval(1, 2),
    pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id="a", seq=1, episode_id=1),
    pb.EpisodeRequest(schema_version=SCHEMA_VERSION, episode_id=1),
    pb.SampleRequest(schema_version=SCHEMA_VERSION, run=RUN_R, learner_id="l", request_id=1,
                     num_minibatches=2, batch_size=8),
    pb.ReplayStatus(schema_version=SCHEMA_VERSION, size_episodes=3, rejects={"x": 1}),
    pb.Metrics(schema_version=SCHEMA_VERSION, service="s", step=1, values={"a": 1.0}),
    pb.Reject(schema_version=SCHEMA_VERSION, reason="bad_shape", detail="d"),
    pb.RunProgress(schema_version=SCHEMA_VERSION, epoch=1, epochs=3),
    pb.ClustererStateRequest(schema_version=SCHEMA_VERSION),
    pb.ClustererState(schema_version=SCHEMA_VERSION,
                      failed_goals=array_to_msg(np.zeros((2, 3), np.float32))),
]]


def other_schema() -> st.SearchStrategy[int]:
    return st.integers(0, 2**32 - 1).filter(lambda v: v != SCHEMA_VERSION)
