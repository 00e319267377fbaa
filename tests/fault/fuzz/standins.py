"""The test's stand-ins for the replays of `fz-actor` and `fz-learner`."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator

import yaml

from hercs.config import HercsConfig
from hercs.net.transport import PendingReply, Transport
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from tests.fault.fuzz.probes import make_batch
from tests.fault.fuzz.runs import (
    ACK_EVERY_S,
    KA,
    KL,
    LEARNER_B,
    LEARNER_N,
    RUN_L,
    VALID_BATCH_EVERY_S,
    WAIT_S,
)


def parked(queries: queue.Queue[PendingReply], stop: threading.Event) -> Iterator[PendingReply]:
    """The queries a stand-in parked, one at a time, until it is told to stop (polled, so
    that a stop is seen within 0.2 s)."""
    while not stop.is_set():
        try:
            yield queries.get(timeout=0.2)
        except queue.Empty:
            continue


class ActorRunReplay:
    """Plays `fz-actor`'s replay: serves the run's config and acks each insert after
    `ACK_EVERY_S` (so the actor rolls out slowly), recording the episode's policy version."""

    def __init__(self, transport: Transport, config: HercsConfig) -> None:
        self.versions: queue.Queue[int] = queue.Queue()
        self._inserts: queue.Queue[PendingReply] = queue.Queue()
        self._stop = threading.Event()
        config_yaml = yaml.safe_dump(config.to_dict()).encode()
        transport.serve(KA.config, lambda _: config_yaml)
        transport.serve_deferred(KA.insert, self._inserts.put)
        self._thread = threading.Thread(target=self._ack, name="fz-acker", daemon=True)
        self._thread.start()

    def _ack(self) -> None:
        for pending in parked(self._inserts, self._stop):
            episode = pb.Episode.FromString(pending.payload)
            if self._stop.wait(ACK_EVERY_S):
                return
            pending.reply(pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id=episode.actor_id,
                                       seq=episode.seq, episode_id=episode.seq)
                          .SerializeToString())
            self.versions.put(int(episode.policy_version))

    def next_versions(self, until: Callable[[int], bool], what: str) -> list[int]:
        """Policy versions of acked episodes, up to and including the first that `until`
        accepts."""
        seen = []
        deadline = time.monotonic() + WAIT_S
        while True:
            try:
                seen.append(self.versions.get(timeout=max(deadline - time.monotonic(), 0.01)))
            except queue.Empty:
                raise AssertionError(f"no episode {what} within {WAIT_S} s; versions since: "
                                     f"{sorted(set(seen))}") from None
            if until(seen[-1]):
                return seen

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)


class LearnerRunReplay:
    """Plays `fz-learner`'s `replay/sample`: each SampleRequest is answered with the next
    queued payload; with none queued, with a valid batch every `VALID_BATCH_EVERY_S` once
    `valid` is set, else held. As the replay does, a new request replaces the one held (the
    learner asks again when a reply is overdue, `ASK_AGAIN_S`, and no longer waits for the
    first): the held one is answered `expired` and the next payload goes to the new one."""

    def __init__(self, transport: Transport) -> None:
        self.valid = threading.Event()
        self.requests_seen = 0
        self.odd_requests: list[str] = []
        self._valid_batch = make_batch(99).SerializeToString()
        self._requests: queue.Queue[PendingReply] = queue.Queue()
        self._payloads: queue.Queue[bytes] = queue.Queue()
        self._served = 0
        self._cond = threading.Condition()
        self._stop = threading.Event()
        transport.serve_deferred(KL.sample, self._requests.put)
        transport.serve(KL.status_at, self._status_at)
        self._thread = threading.Thread(target=self._serve, name="fz-sampler", daemon=True)
        self._thread.start()

    def _status_at(self, raw: bytes) -> bytes:
        """`replay/status_at`: the counters of the moment the learner names (its epoch row)."""
        samples = pb.ReplayStatusRequest.FromString(raw).samples
        return pb.ReplayStatus(schema_version=SCHEMA_VERSION, samples=samples, inserts=100,
                               env_steps=5000, size_transitions=4242).SerializeToString()

    def _check(self, raw: bytes) -> None:
        msg = pb.SampleRequest.FromString(raw)
        if (msg.schema_version, msg.run, msg.num_minibatches, msg.batch_size) != (
                SCHEMA_VERSION, RUN_L, LEARNER_N, LEARNER_B):
            self.odd_requests.append(str(msg))

    def _serve(self) -> None:
        for pending in parked(self._requests, self._stop):
            self.requests_seen += 1
            self._check(pending.payload)
            payload = None
            while payload is None and not self._stop.is_set():
                pending = self._newest(pending)
                try:
                    payload = self._payloads.get(timeout=0.05)
                except queue.Empty:
                    if self.valid.is_set() and not self._stop.wait(VALID_BATCH_EVERY_S):
                        payload = self._valid_batch
            if payload is None:
                return  # closing: the transport answers the held query `unavailable`
            pending.reply(payload)
            with self._cond:
                self._served += 1
                self._cond.notify_all()

    def _newest(self, held: PendingReply) -> PendingReply:
        """The learner's newest request: any that came after `held` replaces it."""
        while True:
            try:
                newer = self._requests.get_nowait()
            except queue.Empty:
                return held
            held.reply_error(Reason.EXPIRED, "the learner asked again")
            self.requests_seen += 1
            self._check(newer.payload)
            held = newer

    def answer(self, payloads: list[bytes]) -> None:
        """Answer the learner's next requests with `payloads`, one each; returns once all were
        sent (which needs the learner to have asked again after each)."""
        with self._cond:
            target = self._served + len(payloads)
        for payload in payloads:
            self._payloads.put(payload)
        with self._cond:
            assert self._cond.wait_for(lambda: self._served >= target, WAIT_S), (
                f"the learner stopped asking for batches ({self._served} of {target} served)")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
