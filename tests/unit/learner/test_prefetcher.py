"""The learner's prefetcher keeps exactly `learner.prefetch_depth` batches sampled ahead of the
update loop (each is one cycle of policy lag in the asynchronous schedule). Driven with a
stand-in transport that answers from a real ReplayTable; no Zenoh."""

from __future__ import annotations

import logging
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides
from hercs.learner.builder import LearnerBuilder
from hercs.learner.prefetch import ASK_AGAIN_S, Prefetcher
from hercs.net.transport import TransportTimeout
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.builder import ReplayBuilder
from hercs.wire.codec import batch_to_bytes, stats_to_msg

WAIT_S = 10.0


class AnsweringTransport:
    """Answers every sample request with a valid Batch and counts them."""

    def __init__(self, config: HercsConfig) -> None:
        self.config = config
        self.table = ReplayBuilder(config).table(rng=np.random.default_rng(0))
        for seq in range(4):
            self.table.store_episode(random_episode(self.table.spec, np.random.default_rng(seq),
                                                    seq=seq))
        self.requests = 0
        self.asked = threading.Condition()
        self.kept: list[tuple[str, int]] = []
        """(learner_incarnation, samples_kept) of every request."""

    def request(self, key: str, payload: bytes, *, timeout_s: float) -> bytes:
        asked = pb.SampleRequest.FromString(payload)
        self.kept.append((asked.learner_incarnation, asked.samples_kept))
        t = self.config.training
        result = self.table.draw(t.minibatches_per_cycle, self.config.ddpg.batch_size)
        o_state, g_state = self.table.normalizers.state()
        header = pb.Batch(schema_version=SCHEMA_VERSION, o_stats=stats_to_msg(o_state),
                          g_stats=stats_to_msg(g_state))
        with self.asked:
            self.requests += 1
            self.asked.notify_all()
        return batch_to_bytes(header, result.minibatches)

    def wait_for(self, count: int, timeout_s: float = WAIT_S) -> bool:
        with self.asked:
            return self.asked.wait_for(lambda: self.requests >= count, timeout_s)


def start(depth: int, kept: int = 0, answering: type[AnsweringTransport] = AnsweringTransport
          ) -> tuple[Prefetcher, AnsweringTransport, threading.Event]:
    config = apply_overrides(HercsConfig(), [
        "task.name=reach", "run.method=her", "training.minibatches_per_cycle=2",
        "ddpg.batch_size=8", "replay.buffer_transitions=5000",
        f"learner.prefetch_depth={depth}"])
    transport = answering(config)
    stop = threading.Event()

    def start_thread(target, *, name):
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        return thread

    runtime = SimpleNamespace(stop=stop, transport=transport, ident="learner-test",
                              keys=SimpleNamespace(sample="sample"), start_thread=start_thread)
    return (LearnerBuilder(config).prefetcher(runtime, version=lambda: 0, samples_kept=kept),
            transport, stop)


@pytest.mark.parametrize("depth", [0, 1, 3], ids=lambda d: f"depth{d}")
def test_the_prefetcher_samples_exactly_depth_batches_ahead(depth: int) -> None:
    prefetcher, transport, stop = start(depth)
    try:
        assert transport.wait_for(depth)
        # nothing more is asked for while the loop takes nothing (a bounded look for a
        # request that must not come)
        assert not transport.wait_for(depth + 1, timeout_s=0.5)
        for taken in range(1, 4):
            assert prefetcher.get() is not None
            # each batch taken lets exactly one more be sampled: `depth` stay ahead
            assert transport.wait_for(depth + taken)
            assert not transport.wait_for(depth + taken + 1, timeout_s=0.3)
    finally:
        stop.set()


def test_each_request_tells_the_replay_what_the_learner_has_kept() -> None:
    """From the checkpoint's count up, by every batch received (SampleRequest.samples_kept),
    under one incarnation per process: what the replay's limiter resyncs to."""
    prefetcher, transport, stop = start(1, kept=80)
    try:
        for taken in range(1, 4):
            assert prefetcher.get() is not None
            assert transport.wait_for(taken + 1)
        n = prefetcher.shape.minibatches
        incarnations = {name for name, _ in transport.kept}
        assert len(incarnations) == 1 and next(iter(incarnations)).startswith("learner-test@")
        assert [kept for _, kept in transport.kept[:4]] == [80 + i * n for i in range(4)]
    finally:
        stop.set()
    other, _, stop2 = start(1)
    stop2.set()
    assert other.incarnation != prefetcher.incarnation


class LosingTransport(AnsweringTransport):
    """The first request's reply never comes (a get Zenoh routed to a replay killed a moment
    before): it ends only at its own timeout, as `hercs.net.transport.request` does."""

    def __init__(self, config: HercsConfig) -> None:
        super().__init__(config)
        self.timeouts: list[float] = []
        self.requested: list[pb.SampleRequest] = []

    def request(self, key: str, payload: bytes, *, timeout_s: float) -> bytes:
        self.timeouts.append(timeout_s)
        self.requested.append(pb.SampleRequest.FromString(payload))
        if len(self.timeouts) == 1:
            raise TransportTimeout(key, timeout_s, "no reply")
        return super().request(key, payload, timeout_s=timeout_s)


def test_a_request_whose_reply_is_lost_is_asked_again_within_a_bound_and_quietly(
        caplog: pytest.LogCaptureFixture) -> None:
    """Before, a sample request waited `replay.sample_timeout_s` (10 min) for its reply, and a
    lost one left the learner, and in lockstep the whole run, idle that long. Now no request
    waits longer than ASK_AGAIN_S; an overdue one is sent again as it was (the same cycle and
    count) with no warning, since a replay may park a request that long on purpose."""
    prefetcher, transport, stop = start(1, kept=40, answering=LosingTransport)
    assert isinstance(transport, LosingTransport)
    try:
        with caplog.at_level(logging.WARNING, logger="hercs.learner"):
            assert prefetcher.get() is not None
        assert transport.timeouts[:2] == [ASK_AGAIN_S, ASK_AGAIN_S]
        assert prefetcher.sample_timeout_s > ASK_AGAIN_S
        first, again = transport.requested[:2]
        assert (again.weights_version, again.samples_kept, again.learner_incarnation) == (
            first.weights_version, first.samples_kept, first.learner_incarnation)
        assert again.request_id > first.request_id
        assert prefetcher.asked_again == 1 and not caplog.records, caplog.records
    finally:
        stop.set()
