"""Round trips of every message and the array codec's strictness."""

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.errors import InvalidMessage
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_registry import task_spec
from hercs.wire.batch import TRANSITION_FIELDS, TransitionBatch
from hercs.wire.codec import (
    array_to_msg,
    arrays_to_named,
    batch_to_bytes,
    episode_to_msg,
    minibatch_to_msg,
    msg_to_array,
    msg_to_episode,
    msg_to_stats,
    named_to_arrays,
    stats_to_msg,
)
from hercs.wire.validation import decode_minibatch

PUSH = task_spec("push")  # obs 25, goal 3, action 4: the minibatches below


@pytest.mark.parametrize(
    "value",
    [
        np.arange(12, dtype=np.float32).reshape(3, 4),
        np.array([[1.5, -2.0]], dtype=np.float64),
        np.array([1, -2, 3], dtype=np.int64),
        np.array([True, False]),
        np.zeros((0, 3), dtype=np.float32),
        np.asfortranarray(np.arange(6, dtype=np.int32).reshape(2, 3)),
        np.arange(4, dtype=">f4"),
    ],
    ids=["f32-2d", "f64", "i64", "bool", "empty", "fortran-order", "big-endian-input"],
)
def test_array_round_trip(value: np.ndarray) -> None:
    wire = pb.Array.FromString(array_to_msg(value).SerializeToString())
    back = msg_to_array(wire)
    assert back.shape == value.shape
    assert back.dtype.name == value.dtype.name
    np.testing.assert_array_equal(back, value)


def test_array_bytes_are_little_endian() -> None:
    msg = array_to_msg(np.array([1.0], dtype=np.float32))
    assert msg.data == b"\x00\x00\x80\x3f"


def test_array_with_wrong_byte_count_is_rejected() -> None:
    msg = array_to_msg(np.zeros((2, 3), dtype=np.float32))
    msg.shape[:] = [2, 4]
    with pytest.raises(InvalidMessage) as err:
        msg_to_array(msg, where="Episode.obs")
    assert err.value.reason == "bad_array"
    assert "Episode.obs" in err.value.detail and "24 data bytes" in err.value.detail


@pytest.mark.parametrize(
    ("shape", "data", "match"),
    [([2**32, 2**32, 4], b"", "dimension above"),  # np.prod wraps to 0 bytes in int64
     ([2**31 - 1, 2**31 - 1, 4, 4], b"\0" * 4, "does not match|expected"),
     ([0, 2**31 - 1, 2**31 - 1, 2**31 - 1], b"", "numpy can"),  # 0 bytes, numpy overflows
     ([0, 5], b"", None),  # a real empty array
     ([1] * 9, b"\0" * 4, "9 dimensions"),
     ([-1, 1], b"", "negative dimension")],
    ids=["wraps-int64", "huge-product", "empty-with-huge-dims", "empty", "too-many-dims",
         "negative"],
)
def test_shapes_that_overflow_or_abuse_the_decoder_are_rejected(shape: list[int], data: bytes,
                                                               match: str | None) -> None:
    msg = pb.Array(dtype="float32", shape=shape, data=data)
    if match is None:
        assert msg_to_array(msg).size == 0
        return
    with pytest.raises(InvalidMessage) as err:
        msg_to_array(msg, where="Batch.minibatches[0].o")
    assert err.value.reason == "bad_array"
    assert "Batch.minibatches[0].o" in err.value.detail


def test_unknown_dtype_is_rejected() -> None:
    msg = array_to_msg(np.zeros(2, dtype=np.float32))
    msg.dtype = "complex64"
    with pytest.raises(InvalidMessage, match="bad_dtype"):
        msg_to_array(msg)


def test_episode_round_trip() -> None:
    spec = task_spec("push")
    episode = random_episode(spec, np.random.default_rng(0), actor_id="a-1", seq=7)
    episode.success = True
    episode.policy_version = 12
    wire = episode_to_msg(episode, run="r1", task="push").SerializeToString()
    msg = pb.Episode.FromString(wire)
    assert (msg.schema_version, msg.run, msg.task) == (SCHEMA_VERSION, "r1", "push")
    back = msg_to_episode(msg)
    for name in ("obs", "ag", "g", "actions"):
        np.testing.assert_array_equal(getattr(back, name), getattr(episode, name))
    assert (back.actor_id, back.seq, back.success, back.policy_version) == ("a-1", 7, True, 12)


def test_normalizer_stats_round_trip() -> None:
    rng = np.random.default_rng(1)
    state = {"sum": rng.normal(size=25), "sumsq": rng.random(25), "count": 1234.0,
             "mean": rng.normal(size=25), "std": rng.random(25)}
    back = msg_to_stats(pb.NormalizerStats.FromString(stats_to_msg(state).SerializeToString()),
                        where="o_stats")
    assert back["count"] == 1234.0
    for name in ("sum", "sumsq", "mean", "std"):
        np.testing.assert_array_equal(back[name], state[name])


def test_named_arrays_round_trip_and_duplicates() -> None:
    params = {"fc1.weight": np.ones((4, 3), np.float32), "fc1.bias": np.zeros(4, np.float32)}
    weights = pb.Weights(version=3, actor_params=arrays_to_named(params))
    back = named_to_arrays(pb.Weights.FromString(weights.SerializeToString()).actor_params,
                           where="Weights.actor_params")
    assert list(back) == list(params)
    np.testing.assert_array_equal(back["fc1.weight"], params["fc1.weight"])
    weights.actor_params.append(weights.actor_params[0])
    with pytest.raises(InvalidMessage, match="duplicate"):
        named_to_arrays(weights.actor_params, where="Weights.actor_params")


def test_minibatch_round_trip() -> None:
    rng = np.random.default_rng(2)
    batch = TransitionBatch(o=rng.random((8, 25)), g=rng.random((8, 3)), u=rng.random((8, 4)),
                            r=-rng.integers(0, 2, 8), o2=rng.random((8, 25)))
    msg = minibatch_to_msg(batch)
    assert {f.name for f, _ in msg.ListFields()} == set(TRANSITION_FIELDS)
    back = decode_minibatch(pb.Minibatch.FromString(msg.SerializeToString()), PUSH,
                            batch_size=8)
    assert isinstance(back, TransitionBatch)
    for name, value, got in zip(TRANSITION_FIELDS, batch, back, strict=True):
        np.testing.assert_array_equal(got, value.astype(np.float32), err_msg=name)
        assert got.dtype == np.float32


def _random_minibatches(count: int, batch_size: int, seed: int) -> list[TransitionBatch]:
    rng = np.random.default_rng(seed)
    return [TransitionBatch(o=rng.random((batch_size, 25), np.float32),
                            g=rng.random((batch_size, 3), np.float32),
                            u=rng.random((batch_size, 4), np.float32),
                            r=-rng.integers(0, 2, batch_size).astype(np.float32),
                            o2=rng.random((batch_size, 25), np.float32))
            for _ in range(count)]


# 0, 1 and 40 minibatches; 12,000 rows make one minibatch ~2.8 MB, a 4-byte length prefix
@pytest.mark.parametrize(("count", "batch_size"), [(0, 256), (1, 1), (40, 256), (1, 12_000)])
def test_batch_to_bytes_is_the_message_serialize_to_string_gives(count: int,
                                                                   batch_size: int) -> None:
    minibatches = _random_minibatches(count, batch_size, seed=count)
    fields = {"schema_version": SCHEMA_VERSION, "request_id": 7, "cluster_draws": [3, 0, 5],
              "samples_served": 40, "buffer_moved_share": 0.25, "policy_lags": [1, -2],
              "o_stats": stats_to_msg({"sum": np.ones(3), "sumsq": np.ones(3), "count": 2.0,
                                       "mean": np.ones(3), "std": np.ones(3)})}
    plain = pb.Batch(**fields, minibatches=[minibatch_to_msg(mb) for mb in minibatches])
    fast = pb.Batch.FromString(batch_to_bytes(pb.Batch(**fields), minibatches))
    assert fast == plain
    for mb, msg in zip(minibatches, fast.minibatches, strict=True):
        np.testing.assert_array_equal(decode_minibatch(msg, PUSH, batch_size=batch_size).o, mb.o)
    if minibatches:
        with pytest.raises(ValueError, match="must not hold minibatches"):
            batch_to_bytes(plain, minibatches)


def _sample_of_each_message() -> list:
    arr = array_to_msg(np.ones((8, 3), np.float32))
    stats = stats_to_msg({"sum": np.ones(3), "sumsq": np.ones(3), "count": 2.0,
                          "mean": np.ones(3), "std": np.ones(3)})
    v = SCHEMA_VERSION
    return [
        pb.InsertAck(schema_version=v, actor_id="a", seq=3, episode_id=9, duplicate=True),
        pb.EpisodeHeader(schema_version=v, episode_id=9, actor_id="a", seq=3, success=False,
                         final_achieved_goal=array_to_msg(np.ones(3, np.float32)),
                         desired_goal=array_to_msg(np.zeros(3, np.float32)), energy=0.25,
                         cluster=-1, policy_version=4),
        pb.SampleRequest(schema_version=v, run="r", learner_id="l", request_id=5,
                         num_minibatches=40, batch_size=256),
        pb.Batch(schema_version=v, request_id=5, minibatches=[pb.Minibatch(o=arr)],
                 o_stats=stats, g_stats=stats, cluster_draws=[32] * 8,
                 samples_served=40, buffer_moved_share=0.5),
        pb.ReplayStatusRequest(schema_version=v, samples=40),
        pb.ClusterModel(schema_version=v, version=2, centroids=arr, fitted_on=150,
                        failures_seen=300),
        pb.Weights(schema_version=v, version=7, o_stats=stats, g_stats=stats, epoch=1,
                   evaluate=True, actor_params=arrays_to_named({"w": np.ones(2, np.float32)})),
        pb.EvalResult(schema_version=v, epoch=1, weights_version=7, episodes=20,
                      success_rate=0.35, mean_final_distance=0.08),
        pb.ReplayStatus(schema_version=v, size_episodes=10, size_transitions=500, inserts=12,
                        duplicates=2, samples=40, rate_limiter="ok",
                        rejects={"non_finite": 1}, cluster_sizes=[1, 2], cluster_model_version=1),
        pb.Metrics(schema_version=v, service="learner", step=3, values={"critic_loss": 0.5}),
        pb.Reject(schema_version=v, reason="bad_shape", detail="Episode.obs: shape (3,)"),
    ]


@pytest.mark.parametrize("msg", _sample_of_each_message(),
                         ids=lambda m: type(m).DESCRIPTOR.name)
def test_every_message_round_trips(msg) -> None:
    back = type(msg).FromString(msg.SerializeToString())
    assert back == msg
    assert back.schema_version == SCHEMA_VERSION


def test_weights_round_trip() -> None:
    from hercs.wire.codec import msg_to_weight_arrays, weights_to_msg

    params = {"fc.weight": np.ones((2, 3), np.float32)}
    stats = {"sum": np.ones(3), "sumsq": np.ones(3), "count": 4.0, "mean": np.ones(3),
             "std": np.ones(3)}
    msg = weights_to_msg(version=5, actor_params=params, o_stats=stats, g_stats=stats,
                         epoch=2, evaluate=True)
    back = pb.Weights.FromString(msg.SerializeToString())
    assert (back.schema_version, back.version, back.epoch, back.evaluate) == (
        SCHEMA_VERSION, 5, 2, True)
    actor, o_stats, g_stats = msg_to_weight_arrays(back)
    np.testing.assert_array_equal(actor["fc.weight"], params["fc.weight"])
    assert o_stats["count"] == g_stats["count"] == 4.0
