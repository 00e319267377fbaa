"""hercs.wire.served: the served batch's one field list (its Python types against the wire
messages) and its encode/decode pair."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.config import HercsConfig
from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.rl.normalizer import Normalizer
from hercs.wire.batch import TRANSITION_FIELDS, TransitionBatch, transition_shapes
from hercs.wire.served import (
    BATCH_FIELDS,
    COUNTER_FIELDS,
    ReplayCounters,
    ServedBatch,
    counters_to_msg,
    decode_served_batch,
    decode_status,
    msg_to_counters,
    served_batch_to_bytes,
    status_request,
)

SPEC = HercsConfig().task.spec
ENVELOPE = {"schema_version", "request_id"}


def test_the_python_types_hold_the_wire_messages_fields_and_no_others() -> None:
    assert set(COUNTER_FIELDS) == {f.name for f in pb.ReplayStatus.DESCRIPTOR.fields} - ENVELOPE
    assert set(BATCH_FIELDS) == {f.name for f in pb.Batch.DESCRIPTOR.fields} - ENVELOPE
    assert set(transition_shapes(SPEC, 4)) == set(TRANSITION_FIELDS)


def _batch(rng: np.random.Generator, *, minibatches: int = 3, rows: int = 8) -> ServedBatch:
    shapes = transition_shapes(SPEC, rows)
    norm = Normalizer(SPEC.obs_dim)
    norm.update(rng.standard_normal((5, SPEC.obs_dim)))
    g_norm = Normalizer(SPEC.goal_dim)
    g_norm.update(rng.standard_normal((5, SPEC.goal_dim)))
    return ServedBatch(
        minibatches=[TransitionBatch(**{name: rng.standard_normal(shape).astype(np.float32)
                                        for name, shape in shapes.items()})
                     for _ in range(minibatches)],
        o_stats=norm.state_dict(), g_stats=g_norm.state_dict(),
        cluster_draws=np.arange(8, dtype=np.int64), policy_lags=np.array([-2, 0, 3]),
        sampled_moved=5, sampled_transitions=minibatches * rows, samples_served=40,
        buffer_moved_share=0.25)


COUNTERS = ReplayCounters(size_episodes=10, size_transitions=500, inserts=12, duplicates=1,
                          samples=40, rate_limiter="ok", rejects={"non_finite": 2},
                          cluster_sizes=[3, 7], cluster_model_version=4, env_steps=600,
                          policy_lag=1.5, policy_lag_request=0.5, buffer_moved_share=0.25,
                          inserts_waiting=1, samples_waiting=0)


def test_a_served_batch_comes_back_from_the_wire_as_it_was_sent() -> None:
    sent = _batch(np.random.default_rng(0))
    raw = served_batch_to_bytes(sent, request_id=9)
    assert pb.Batch.FromString(raw).request_id == 9
    got = decode_served_batch(raw, spec=SPEC, k=8, batch_size=8, num_minibatches=3)
    for name in ("cluster_draws", "policy_lags"):
        np.testing.assert_array_equal(getattr(got, name), getattr(sent, name))
    assert (got.sampled_moved, got.sampled_transitions) == (5, 24)
    assert (got.samples_served, got.buffer_moved_share) == (40, 0.25)
    for a, b in zip(got.minibatches, sent.minibatches, strict=True):
        for name in TRANSITION_FIELDS:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_the_counters_travel_on_their_own_channel_and_come_back_as_sent() -> None:
    """`replay/status_at`: the request names the moment, the reply is the counters, checked."""
    assert pb.ReplayStatusRequest.FromString(status_request(40)).samples == 40
    raw = counters_to_msg(COUNTERS).SerializeToString()
    assert decode_status(raw, max_bytes=1 << 16) == COUNTERS
    assert msg_to_counters(counters_to_msg(COUNTERS)) == COUNTERS
    bad = counters_to_msg(COUNTERS)
    bad.buffer_moved_share = 2.0
    with pytest.raises(InvalidMessage, match=r"ReplayStatus\.buffer_moved_share 2\.0 is not"):
        decode_status(bad.SerializeToString(), max_bytes=1 << 16)
    bad.buffer_moved_share = float("nan")
    with pytest.raises(InvalidMessage, match=r"ReplayStatus\.buffer_moved_share nan is not"):
        decode_status(bad.SerializeToString(), max_bytes=1 << 16)
    with pytest.raises(InvalidMessage):
        decode_status(b"\xff\xff garbage", max_bytes=1 << 16)
    with pytest.raises(InvalidMessage):
        decode_status(raw, max_bytes=8)


def test_a_batch_the_learner_did_not_ask_for_is_refused_naming_what_is_wrong() -> None:
    raw = served_batch_to_bytes(_batch(np.random.default_rng(1)), request_id=1)
    with pytest.raises(InvalidMessage, match="3 minibatches, asked for 4"):
        decode_served_batch(raw, spec=SPEC, k=8, batch_size=8, num_minibatches=4)
    with pytest.raises(InvalidMessage, match=r"Batch\.minibatches\[0\]\.o"):
        decode_served_batch(raw, spec=SPEC, k=8, batch_size=16, num_minibatches=3)
    with pytest.raises(InvalidMessage, match=r"Batch\.cluster_draws: 8 values, expected 4"):
        decode_served_batch(raw, spec=SPEC, k=4, batch_size=8, num_minibatches=3)
    msg = pb.Batch.FromString(raw)
    msg.buffer_moved_share = 1.5
    with pytest.raises(InvalidMessage, match=r"Batch\.buffer_moved_share 1\.5 is not a share"):
        decode_served_batch(msg.SerializeToString(), spec=SPEC, k=8, batch_size=8,
                            num_minibatches=3)


def test_a_mean_that_is_not_a_number_reads_as_zero() -> None:
    msg = counters_to_msg(ReplayCounters(inserts=3))
    msg.policy_lag = float("nan")
    assert msg_to_counters(msg).policy_lag == 0.0 and msg_to_counters(msg).inserts == 3
