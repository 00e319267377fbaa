"""One field broken, per message type: a hypothesis strategy of `Probe`s for each input."""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import strategies as st

from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.replay_messages import MAX_BATCH_SIZE, MAX_MINIBATCHES_PER_REQUEST
from hercs.wire.codec import array_to_msg, msg_to_array
from tests.fault.fuzz.probes import (
    ARRAY_KINDS,
    BASE_BATCHES,
    BASE_EPISODES,
    BASE_WEIGHTS,
    CENTROIDS_ARRAY,
    EPISODE_ARRAY,
    FIRST_MODEL_VERSION,
    HEADER_ARRAY,
    LOADED_ARRAY,
    MINIBATCH_ARRAY,
    Probe,
    base_episode,
    break_array,
    make_eval,
    make_header,
    make_model,
    other_schema,
    unknown_field,
)
from tests.fault.fuzz.runs import HEADER_MAX_BYTES, LEARNER_N, RUN_A, RUN_L, RUN_R, SEEDS, VALID, K


def break_field(msg: Any, name: str, array_kind: str, rng: np.random.Generator) -> None:
    """Breaks the Array field `name` of `msg` as `array_kind` says (break_array); "missing"
    clears the field."""
    if array_kind == "missing":
        msg.ClearField(name)
    else:
        getattr(msg, name).CopyFrom(break_array(msg_to_array(getattr(msg, name)), array_kind,
                                                rng))


@st.composite
def schema_break(draw: st.DrawFn, msg: Any) -> str:
    """Give `msg` a schema version other than this build's, in place; the reason a receiver
    refuses it with."""
    msg.schema_version = draw(other_schema())
    return "schema_version"


@st.composite
def episode_probes(draw: st.DrawFn) -> Probe:
    what = draw(st.sampled_from(["schema", "run", "task", "actor", "seq", "array", "array",
                                 "array", "array", "array", "valid-extreme", "valid-new"]))
    seed = draw(SEEDS)
    rng = np.random.default_rng(seed)
    msg = pb.Episode()
    msg.CopyFrom(BASE_EPISODES[seed % len(BASE_EPISODES)])
    kind = what
    if what == "schema":
        expect: str | None = draw(schema_break(msg))
    elif what == "run":
        msg.run = draw(st.sampled_from(["", "t", RUN_A, RUN_L, RUN_R + "x", RUN_R.upper()]))
        expect = "unknown_run"
    elif what == "task":
        msg.task = draw(st.sampled_from(["", "push", "pick", "slide", "Reach", "reach "]))
        expect = "wrong_task"
    elif what == "actor":
        msg.actor_id = ""
        expect = "missing_field"
    elif what == "seq":  # beyond int64: the replay's store keeps seq as int64
        msg.seq = draw(st.integers(2**63, 2**64 - 1))
        expect = "bad_value"
    elif what == "array":
        name = draw(st.sampled_from(["obs", "ag", "g", "actions"]))
        array_kind = draw(st.sampled_from(ARRAY_KINDS))
        kind = f"array:{name}:{array_kind}"
        break_field(msg, name, array_kind, rng)
        expect = EPISODE_ARRAY[array_kind]
    elif what == "valid-extreme":  # a new pair, extreme but valid values
        msg.actor_id = draw(st.sampled_from(["ü/∞ actor", "x" * 2000, "a@b@c", "fz-extreme"]))
        msg.seq = draw(st.integers(0, 2**63 - 1))
        msg.policy_version = draw(st.sampled_from([-(2**63), 2**63 - 1, -1, 0, 7]))
        msg.success = draw(st.booleans())
        msg.obs.CopyFrom(break_array(msg_to_array(msg.obs), "extreme", rng))
        expect = VALID
    else:  # a new valid episode
        msg.CopyFrom(base_episode(seed, actor="fz-new"))
        msg.seq = seed % 1000  # pairs repeat across examples: duplicates
        expect = VALID
    return Probe(msg.SerializeToString(), f"episode:{kind}", expect)


@st.composite
def sample_request_probes(draw: st.DrawFn) -> Probe:
    what = draw(st.sampled_from(["schema", "run", "minibatches", "batch_size", "valid",
                                 "valid"]))
    msg = pb.SampleRequest(
        schema_version=SCHEMA_VERSION, run=RUN_R, learner_id=draw(st.text(max_size=8)),
        request_id=draw(st.integers(0, 2**64 - 1)), num_minibatches=draw(st.integers(1, 4)),
        batch_size=draw(st.integers(1, 64)),
        weights_version=draw(st.integers(-(2**63), 2**63 - 1)))
    expect: str | None = VALID
    if what == "schema":
        expect = draw(schema_break(msg))
    elif what == "run":
        msg.run = draw(st.sampled_from(["", RUN_A, RUN_L, "t"]))
        expect = "unknown_run"
    elif what == "minibatches":
        msg.num_minibatches = draw(st.sampled_from([0, MAX_MINIBATCHES_PER_REQUEST + 1, 2**32 - 1]))
        expect = "bad_value"
    elif what == "batch_size":
        msg.batch_size = draw(st.sampled_from([0, MAX_BATCH_SIZE + 1, 2**32 - 1]))
        expect = "bad_value"
    return Probe(msg.SerializeToString(), f"sample:{what}", expect)


@st.composite
def episode_request_probes(draw: st.DrawFn) -> Probe:
    if draw(st.integers(0, 4)) == 0:
        msg = pb.EpisodeRequest(schema_version=draw(other_schema()))
        return Probe(msg.SerializeToString(), "episode-request:schema", "schema_version")
    episode_id = draw(st.one_of(st.integers(0, 400), st.integers(0, 2**64 - 1)))
    msg = pb.EpisodeRequest(schema_version=SCHEMA_VERSION, episode_id=episode_id)
    return Probe(msg.SerializeToString(), "episode-request:id", VALID)


@st.composite
def clusterer_state_probes(draw: st.DrawFn) -> Probe:
    if draw(st.booleans()):
        msg = pb.ClustererStateRequest(schema_version=draw(other_schema()))
        return Probe(msg.SerializeToString(), "state-request:schema", "schema_version")
    payload = pb.ClustererStateRequest(schema_version=SCHEMA_VERSION).SerializeToString()
    return Probe(payload + draw(st.sampled_from([b"", unknown_field(3)])),
                 "state-request:valid", VALID)


@st.composite
def cluster_model_probes(draw: st.DrawFn) -> Probe:
    what = draw(st.sampled_from(["schema", "centroids", "centroids", "centroids", "version0",
                                 "stale", "float64-overflow", "newer"]))
    seed = draw(SEEDS)
    rng = np.random.default_rng(seed)
    msg = make_model(draw(st.integers(1, FIRST_MODEL_VERSION)), seed)
    kind = what
    expect: str | None = None  # a valid model's fate depends on the replay's current one
    if what == "schema":
        expect = draw(schema_break(msg))
    elif what == "centroids":
        array_kind = draw(st.sampled_from(ARRAY_KINDS))
        kind = f"centroids:{array_kind}"
        msg.centroids.CopyFrom(break_array(msg_to_array(msg.centroids), array_kind, rng))
        expect = CENTROIDS_ARRAY[array_kind]
        if expect == VALID:
            expect = None
    elif what == "version0":
        msg.version = 0
        expect = "bad_value"
    elif what == "float64-overflow":  # finite as float64, infinite as the float32 it becomes
        msg.centroids.CopyFrom(array_to_msg(np.full((K, 3), 1e300, np.float64)))
        expect = "bad_value"
    elif what == "newer":
        msg.version = draw(st.one_of(st.integers(4, 40), st.just(2**64 - 1)))
    return Probe(msg.SerializeToString(), f"model:{kind}", expect)


@st.composite
def eval_result_probes(draw: st.DrawFn, *, epoch: int | None = None,
                       version: int | None = None) -> Probe:
    """EvalResults with one field broken; `epoch`/`version` pin the valid fields (the
    learner's pending epoch and its weights version). An epoch above `MAX_SEQUENCE` is valid
    here; the replay, which logs the epoch as an MCAP sequence, refuses it (`bad_value`)."""
    what = draw(st.sampled_from(["schema", "episodes", "success-nonfinite", "success-range",
                                 "distance-nonfinite", "distance-negative", "valid",
                                 "wrong-version"]))
    msg = make_eval(
        draw(st.integers(0, 2**64 - 1)) if epoch is None else epoch,
        draw(st.integers(0, 2**64 - 1)) if version is None else version,
        success=draw(st.floats(0, 1)), distance=draw(st.floats(0, 10)),
        episodes=draw(st.integers(1, 2**32 - 1)))
    expect = VALID
    if what == "schema":
        expect = draw(schema_break(msg))
    elif what == "episodes":
        msg.episodes = 0
        expect = "bad_value"
    elif what == "success-nonfinite":
        msg.success_rate = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
        expect = "non_finite"
    elif what == "success-range":
        msg.success_rate = draw(st.one_of(st.floats(max_value=-1e-9, allow_infinity=False),
                                          st.floats(min_value=1.000001, allow_infinity=False)))
        expect = "bad_value"
    elif what == "distance-nonfinite":
        msg.mean_final_distance = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
        expect = "non_finite"
    elif what == "distance-negative":
        msg.mean_final_distance = draw(st.floats(max_value=-1e-9, allow_infinity=False))
        expect = "bad_value"
    elif what == "wrong-version":
        msg.weights_version = draw(st.integers(0, 2**64 - 1).filter(
            lambda v: v != msg.weights_version))
    return Probe(msg.SerializeToString(), f"eval:{what}", expect)


@st.composite
def header_probes(draw: st.DrawFn) -> Probe:
    what = draw(st.sampled_from(["schema", "goal", "goal", "goal", "oversized", "valid"]))
    seed = draw(SEEDS)
    rng = np.random.default_rng(seed)
    msg = make_header(seed, episode_id=draw(st.integers(0, 2**64 - 1)))
    kind = what
    expect: str | None = VALID
    if what == "schema":
        expect = draw(schema_break(msg))
    elif what == "goal":
        name = draw(st.sampled_from(["final_achieved_goal", "desired_goal"]))
        array_kind = draw(st.sampled_from(ARRAY_KINDS))
        kind = f"goal:{name}:{array_kind}"
        break_field(msg, name, array_kind, rng)
        expect = HEADER_ARRAY[array_kind]
    elif what == "oversized":
        msg.actor_id = "x" * (HEADER_MAX_BYTES + draw(st.integers(1, 100)))
        expect = "oversized"
    return Probe(msg.SerializeToString(), f"header:{kind}", expect)


@st.composite
def stats_break(draw: st.DrawFn, msg: pb.NormalizerStats, rng: np.random.Generator
                ) -> tuple[str, str | None]:
    """Break one part of a NormalizerStats in place; (what, the reason a loader gives)."""
    what = draw(st.sampled_from(["array", "array", "std", "count"]))
    if what == "std":
        std = msg_to_array(msg.std).copy()
        std[int(rng.integers(0, std.size))] = draw(st.sampled_from([0.0, -1.0, -1e-30]))
        array_to_msg(std, out=msg.std)
        return "std", "bad_value"
    if what == "count":
        msg.count = draw(st.sampled_from([-1.0, 0.5, np.nan, np.inf, -np.inf, 1e300 + 0.5]))
        return "count", None if np.isfinite(msg.count) and msg.count > 1e17 else "bad_value"
    part = draw(st.sampled_from(["sum", "sumsq", "mean", "std"]))
    array_kind = draw(st.sampled_from(ARRAY_KINDS))
    getattr(msg, part).CopyFrom(break_array(msg_to_array(getattr(msg, part)), array_kind, rng))
    return f"{part}:{array_kind}", LOADED_ARRAY[array_kind]


@st.composite
def weights_probes(draw: st.DrawFn, *, evaluate: bool | None = None) -> Probe:
    """Weights with one part broken. `evaluate=None`: the flag is drawn."""
    what = draw(st.sampled_from(["schema", "param-missing", "param-extra", "param-duplicate",
                                 "param", "param", "stats", "stats", "version", "valid"]))
    seed = draw(SEEDS)
    rng = np.random.default_rng(seed)
    msg = pb.Weights()
    msg.CopyFrom(BASE_WEIGHTS[seed % len(BASE_WEIGHTS)])
    msg.evaluate = draw(st.booleans()) if evaluate is None else evaluate
    msg.version = draw(st.integers(1000, 2**63 - 1))
    # Epochs within the evaluator's run (its 200) are evaluated, later ones refused.
    msg.epoch = draw(st.one_of(st.integers(0, 2**64 - 1), st.integers(0, 250)))
    kind = what
    expect: str | None = VALID
    params = msg.actor_params
    i = int(rng.integers(0, len(params)))
    if what == "schema":
        expect = draw(schema_break(msg))
    elif what == "param-missing":
        del params[i]
        expect = "bad_value"
    elif what == "param-extra":
        extra = params.add()
        extra.CopyFrom(params[i])
        extra.name = draw(st.sampled_from(["", "l9.weight", params[i].name + "x"]))
        expect = "bad_value"
    elif what == "param-duplicate":
        params.add().CopyFrom(params[i])
        expect = "bad_array"
    elif what == "param":
        array_kind = draw(st.sampled_from(ARRAY_KINDS))
        kind = f"param:{array_kind}"
        params[i].array.CopyFrom(break_array(msg_to_array(params[i].array), array_kind, rng))
        expect = LOADED_ARRAY[array_kind]
        if array_kind == "extreme":
            expect = VALID
    elif what == "stats":
        which = draw(st.sampled_from(["o_stats", "g_stats"]))
        broken, expect = draw(stats_break(getattr(msg, which), rng))
        kind = f"{which}:{broken}"
    elif what == "version":  # beyond int64: an actor tags its episodes' int64 policy_version
        msg.version = draw(st.integers(2**63, 2**64 - 1))
        expect = "bad_value"
    return Probe(msg.SerializeToString(), f"weights:{kind}", expect)


@st.composite
def batch_probes(draw: st.DrawFn) -> Probe:
    what = draw(st.sampled_from(["schema", "count", "minibatch", "minibatch", "minibatch",
                                 "stats", "draws-length", "draws-big", "moved-share",
                                 "valid-extreme"]))
    seed = draw(SEEDS)
    rng = np.random.default_rng(seed)
    msg = pb.Batch()
    msg.CopyFrom(BASE_BATCHES[seed % len(BASE_BATCHES)])
    kind = what
    expect: str | None = VALID
    if what == "schema":
        expect = draw(schema_break(msg))
    elif what == "count":
        n = draw(st.sampled_from([0, 1, LEARNER_N + 1]))
        del msg.minibatches[:]
        msg.minibatches.extend(BASE_BATCHES[0].minibatches[:1] * n)
        expect = "bad_length"
    elif what == "minibatch":
        mb = msg.minibatches[int(rng.integers(0, LEARNER_N))]
        name = draw(st.sampled_from(["o", "g", "u", "r", "o2"]))
        array_kind = draw(st.sampled_from(ARRAY_KINDS))
        kind = f"minibatch:{name}:{array_kind}"
        break_field(mb, name, array_kind, rng)
        expect = MINIBATCH_ARRAY[array_kind]
    elif what == "stats":
        which = draw(st.sampled_from(["o_stats", "g_stats"]))
        broken, expect = draw(stats_break(getattr(msg, which), rng))
        kind = f"{which}:{broken}"
    elif what == "draws-length":
        msg.cluster_draws[:] = [1] * draw(st.sampled_from([1, K - 1, K + 1, 3 * K]))
        expect = "bad_length"
    elif what == "draws-big":  # beyond int64: the learner sums draws in an int64 array
        msg.cluster_draws[int(rng.integers(0, K))] = draw(st.integers(2**63, 2**64 - 1))
        expect = "bad_value"
    elif what == "moved-share":  # a share that is no share, or not a number
        msg.buffer_moved_share = draw(st.sampled_from([np.nan, np.inf, -np.inf, 1.5, -0.1]))
        expect = "bad_value"
    else:  # numbers as large as their types go, lags at their extremes
        msg.request_id = draw(st.integers(0, 2**64 - 1))
        msg.samples_served = draw(st.integers(0, 2**64 - 1))
        msg.buffer_moved_share = draw(st.sampled_from([0.0, 1.0, 5e-324]))
        msg.policy_lags[:] = draw(st.lists(st.integers(-2**63, 2**63 - 1), max_size=4))
        del msg.cluster_draws[:]
    return Probe(msg.SerializeToString(), f"batch:{kind}", expect)


@st.composite
def progress_probes(draw: st.DrawFn) -> Probe:
    msg = pb.RunProgress(schema_version=SCHEMA_VERSION, epoch=draw(st.integers(0, 2**64 - 1)),
                         epochs=draw(st.integers(0, 2**64 - 1)), finished=False)
    if draw(st.booleans()):
        reason = draw(schema_break(msg))
        msg.finished = draw(st.booleans())  # a finished flag in a bad message is not obeyed
        return Probe(msg.SerializeToString(), "progress:schema", reason)
    return Probe(msg.SerializeToString(), "progress:running", VALID)
