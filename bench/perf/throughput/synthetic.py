"""Synthetic actors: pre-generated random Push episodes inserted over Zenoh one at a time,
each awaited until acked (as `hercs.actors.inserter` delivers); and the same episodes put into a
local `ReplayTable` for the in-process references."""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
from collections.abc import Iterator, Sequence

import numpy as np

from bench.common import all_started
from bench.perf.throughput import BenchError
from bench.perf.throughput.plan import K_CLUSTERS, REQUEST_TIMEOUT_S, RUN, SEED
from bench.synthetic_episodes import random_episode
from hercs.net.transport import Transport
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.replay_service.table import ReplayTable
from hercs.rl.seeding import generator
from hercs.rl.task_registry import TaskSpec
from hercs.wire.codec import episode_to_msg
from hercs.wire.episode import EpisodeData
from hercs.wire.validation import parse_message


class SyntheticActor:
    """Inserts pre-generated episodes one at a time, each awaited until acked (as
    `hercs.actors.inserter` delivers), over its own Zenoh client session; acks are timestamped.

    The session stays open across `start`/`stop` runs: every new local session that sends
    large messages gives the replay one more Zenoh shared-memory pool to map (see
    `own_rss_mib`), so the benchmark opens as few as it can.
    """

    def __init__(self, *, name: str, endpoint: str, pool: Sequence[EpisodeData],
                 task: str) -> None:
        self.name = name
        self._pool = pool
        self._task = task
        self._keys = RunKeys(RUN)
        self.transport = Transport.open(mode="client", connect=[endpoint],
                                        connect_timeout_s=30.0)
        self.acks: list[tuple[float, int, float]] = []
        """(ack time, episode id, request latency s) of every run, appended by the sender."""
        self.error: BaseException | None = None
        self._seq = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"synthetic-{self.name}",
                                        daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                seq = self._seq
                episode = dataclasses.replace(self._pool[seq % len(self._pool)],
                                              actor_id=self.name, seq=seq)
                payload = episode_to_msg(episode, run=RUN, task=self._task).SerializeToString()
                sent = time.monotonic()
                raw = self.transport.request(self._keys.insert, payload,
                                             timeout_s=REQUEST_TIMEOUT_S)
                acked = time.monotonic()
                ack = parse_message(raw, pb.InsertAck, max_bytes=1 << 16)
                if ack.seq != seq or ack.duplicate:
                    raise BenchError(f"{self.name}: ack for seq {ack.seq} "
                                     f"(duplicate={ack.duplicate}), expected a new seq {seq}")
                self.acks.append((acked, int(ack.episode_id), acked - sent))
                self._seq += 1
        except BaseException as exc:  # reported by `SyntheticFleet.running`
            if not self._stop.is_set():
                self.error = exc

    def stop(self) -> None:
        """Stop after the insert in flight is acked."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(REQUEST_TIMEOUT_S + 5.0)

    def close(self) -> None:
        self.stop()
        self.transport.close()


class SyntheticFleet:
    """`size` synthetic actors whose sessions are opened once; `running(n)` runs the first n."""

    def __init__(self, *, size: int, endpoint: str, pool: Sequence[EpisodeData],
                 task: str) -> None:
        self.actors: list[SyntheticActor] = []
        try:
            for i in range(size):
                self.actors.append(SyntheticActor(name=f"synthetic-{i}", endpoint=endpoint,
                                                  pool=pool, task=task))
        except BaseException:
            self.close()
            raise

    @contextlib.contextmanager
    def running(self, n: int) -> Iterator[list[SyntheticActor]]:
        """The first `n` actors insert until the block exits; a failed actor raises then."""
        actors = self.actors[:n]
        with all_started(actors, SyntheticActor.start, SyntheticActor.stop):
            yield actors
        errors = [a.error for a in actors if a.error is not None]
        if errors:
            raise BenchError(f"a synthetic actor failed: {errors[0]!r}")

    def acks_between(self, start: float, end: float) -> list[tuple[float, int, float]]:
        return [a for actor in self.actors for a in actor.acks if start <= a[0] < end]

    def newest_episode_id(self) -> int:
        return max((a.acks[-1][1] for a in self.actors if a.acks), default=-1)

    def close(self) -> None:
        for actor in self.actors:
            actor.close()


def episode_pool(spec: TaskSpec, size: int) -> list[EpisodeData]:
    rng = generator(SEED, "bench", "episodes")
    return [random_episode(spec, rng, actor_id="pool", seq=i) for i in range(size)]


def fill_table(table: ReplayTable, pool: Sequence[EpisodeData], episodes: int) -> None:
    for i in range(episodes):
        table.store_episode(dataclasses.replace(pool[i % len(pool)], actor_id="ref", seq=i))


def cluster_centroids(spec: TaskSpec) -> np.ndarray:
    """k centroids spread over the synthetic episodes' goal range (uniform in [−1, 1]³), so
    every cluster gets episodes, as a fitted model would give."""
    return generator(SEED, "bench", "centroids").uniform(
        -1.0, 1.0, size=(K_CLUSTERS, spec.goal_dim)).astype(np.float32)
