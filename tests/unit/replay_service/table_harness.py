"""A ReplayTable without any transport, for its tests: a fake log, a settable clock, waiters
that journal what they were told."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.builder import ReplayBuilder
from hercs.replay_service.table import ReplayTable, SampleCall
from hercs.wire.episode import EpisodeData
from tests.support import Clock

# ρ = 8/4 = 2 updates per episode, N_min = 4, E = 8: d = 2·I − S stays in [0, 16].
# Inserts are admitted while d + 2 ≤ 16, a request of n while I ≥ 4 and d − n ≥ 0.
OVERRIDES = ["task.name=reach", "run.method=her", "training.episodes_per_cycle=4",
             "training.minibatches_per_cycle=8", "replay.rate_tolerance_updates=8",
             "replay.min_episodes_to_sample=4", "replay.buffer_transitions=5000",
             "ddpg.batch_size=16",
             # synthetic episodes act with no weights version: the lag bound has its own tests
             "training.max_policy_lag=-1"]


@dataclass
class Recorder:
    """A waiter that remembers what it was told, and the order across waiters."""

    name: str
    journal: list[str]
    results: list[Any] = field(default_factory=list)
    failures: list[tuple[str, str]] = field(default_factory=list)

    def done(self, result: Any) -> None:
        self.results.append(result)
        self.journal.append(f"done {self.name}")

    def fail(self, reason: str, detail: str) -> None:
        self.failures.append((reason, detail))
        self.journal.append(f"fail {self.name}")


@dataclass
class FakeLog:
    journal: list[str]
    episodes: list[tuple[int, pb.Episode]] = field(default_factory=list)
    fail_next: int = 0

    def append_many(self, episodes: list[tuple[int, pb.Episode]]) -> None:
        if self.fail_next:
            self.fail_next -= 1
            raise OSError(28, "No space left on device")
        for episode_id, msg in episodes:
            self.episodes.append((episode_id, msg))
            self.journal.append(f"log {episode_id}")

    def append_cluster_model(self, msg: pb.ClusterModel) -> None:
        self.journal.append("log model")

    def append_eval_result(self, msg: pb.EvalResult) -> None:
        self.journal.append("log eval")

    def rotation_due(self) -> bool:
        return False

    def start_segment(self, state: pb.ReplayState) -> None:
        raise AssertionError("this log is never full")


@dataclass
class Harness:
    table: ReplayTable
    log: FakeLog
    clock: Clock
    journal: list[str]
    config: HercsConfig

    def episode(self, seq: int, actor: str = "a") -> EpisodeData:
        return random_episode(self.config.task.spec, np.random.default_rng(seq), actor_id=actor,
                              seq=seq)

    def insert(self, seq: int, actor: str = "a", timeout_s: float | None = None) -> Recorder:
        waiter = Recorder(f"insert {actor}/{seq}", self.journal)
        self.table.insert(self.episode(seq, actor), record=pb.Episode(seq=seq),
                          waiter=waiter, timeout_s=timeout_s)
        return waiter

    def sample(self, n: int, name: str = "sample", timeout_s: float | None = None,
               version: int = 0, learner: str = "", kept: int = 0) -> Recorder:
        waiter = Recorder(name, self.journal)
        self.table.sample(SampleCall(num_minibatches=n, batch_size=16, weights_version=version,
                                     samples_kept=kept, learner_incarnation=learner),
                          waiter=waiter, timeout_s=timeout_s)
        return waiter


def make(*extra: str) -> Harness:
    config = apply_overrides(HercsConfig(), [*OVERRIDES, *extra])
    journal: list[str] = []
    log, clock = FakeLog(journal), Clock()
    table = ReplayBuilder(config).table(rng=np.random.default_rng(0), log=log, clock=clock)
    return Harness(table, log, clock, journal, config)

def insert_acted(h: Harness, seq: int, version: int, actor: str = "a") -> Recorder:
    episode = h.episode(seq, actor)
    episode.policy_version = version
    waiter = Recorder(f"insert {actor}/{seq}", h.journal)
    h.table.insert(episode, record=pb.Episode(seq=seq), waiter=waiter)
    return waiter
