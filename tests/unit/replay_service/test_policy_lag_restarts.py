"""Policy lag through restarts: a simulated asynchronous run (one learner, one actor whose
weights arrive a few cycles late) drives the real ReplayTable, and is restarted at several
points the ways a run is: a whole-run resume (also what a Slurm requeue does), a replay
restart, a learner restart. Every lag the served batches carry is checked: never negative,
and within `training.max_policy_lag` once the bound applies, before and after the restart."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.table import Stored
from hercs.wire.episode import EpisodeData
from tests.unit.replay_service.table_harness import Harness, Recorder, make

MAX_LAG = 3
CYCLE = 8  # minibatches per cycle in the harness (training.minibatches_per_cycle)
EPISODES_PER_CYCLE = 4


@dataclass
class Learner:
    """Asks for one cycle at a time; a checkpoint every `every` cycles."""

    incarnation: str = "L@1"
    version: int = 0
    kept: int = 0
    every: int = 5
    checkpoint: tuple[int, int] = (0, 0)
    waiting: Recorder | None = None

    def step(self, h: Harness, lags: list[int]) -> bool:
        if self.waiting is None:
            self.waiting = h.sample(CYCLE, f"{self.incarnation}/{self.version}",
                                    version=self.version, learner=self.incarnation,
                                    kept=self.kept)
        if not self.waiting.results:
            return False
        lags.extend(int(x) for x in self.waiting.results[0].policy_lags)
        self.waiting = None
        self.kept += CYCLE
        self.version += 1
        if self.version % self.every == 0:
            self.checkpoint = (self.version, self.kept)
        return True

    def restart(self, n: int) -> None:
        self.incarnation = f"L@{n}"
        self.version, self.kept = self.checkpoint
        self.waiting = None


@dataclass
class Actor:
    """Acts with the learner's weights as they were `delay` learner steps ago (weights in
    flight, an episode in progress), never older than the replay's last ack asks for."""

    delay: int
    seq: int = 0
    seen: list[int] = field(default_factory=lambda: [0])
    least: int = 0
    waiting: tuple[Recorder, EpisodeData] | None = None
    stored: list[tuple[int, EpisodeData]] = field(default_factory=list)

    def weights(self) -> int:
        recent = self.seen[-1 - self.delay] if len(self.seen) > self.delay else self.seen[0]
        return max(recent, min(self.least, self.seen[-1]))

    def step(self, h: Harness) -> bool:
        if self.waiting is None:
            episode = h.episode(self.seq)
            episode.policy_version = self.weights()
            waiter = Recorder(f"insert {self.seq}", h.journal)
            h.table.insert(episode, record=pb.Episode(seq=self.seq), waiter=waiter)
            self.waiting = (waiter, episode)
        waiter, episode = self.waiting
        if waiter.failures:
            # stale, or after a restart acted with the dead learner's weights that the
            # restarted replay has not seen announced: both superseded, acted again
            assert waiter.failures[0][0] in (Reason.STALE_POLICY, Reason.FUTURE_POLICY), \
                waiter.failures
            self.least = max(self.least, self.seen[-1])
            self.waiting, self.seq = None, self.seq + 1  # acts a new episode with newer weights
            return True
        if not waiter.results:
            return False
        stored = waiter.results[0]
        assert isinstance(stored, Stored)
        if not stored.duplicate:
            self.stored.append((stored.episode_id, episode))
        self.least = max(self.least, stored.next_policy_version)
        self.waiting, self.seq = None, self.seq + 1
        return True


def run_cycles(h: Harness, learner: Learner, actor: Actor, cycles: int, lags: list[int]
               ) -> None:
    """Until the learner has done `cycles` more cycles (the actor acting alongside)."""
    target = learner.version + cycles
    for _ in range(200 * cycles):
        moved = actor.step(h)
        if learner.step(h, lags):
            actor.seen.append(learner.version)
            moved = True
        if learner.version >= target:
            return
        assert moved, "neither side can move: the limiter holds both"
    raise AssertionError(f"the learner reached version {learner.version}, not {target}")


def restarted_replay(actor: Actor) -> Harness:
    """A new replay process: its table recovers every acked episode from the log."""
    h = make(f"training.max_policy_lag={MAX_LAG}")
    assert h.table.recover(sorted(actor.stored, key=lambda pair: pair[0])) == []
    return h


def check(lags: list[int], *, what: str) -> None:
    got = np.asarray(lags)
    assert got.size, f"{what}: no lag recorded"
    assert got.min() >= 0, f"{what}: negative policy lag {sorted(set(got[got < 0]))}"
    assert got.max() <= MAX_LAG, f"{what}: lag {got.max()} past max_policy_lag={MAX_LAG}"


@pytest.mark.parametrize("at_cycle", [3, 7, 12, 19], ids=lambda c: f"cycle{c}")
@pytest.mark.parametrize("how", ["whole-run", "replay", "learner"])
def test_lag_stays_within_zero_and_the_bound_through_a_restart(how: str, at_cycle: int) -> None:
    """Checkpoints every 5 cycles: at cycles 7, 12 and 19 the log holds episodes acted after
    the learner's checkpoint (the surplus the resume's learner redoes); at 3 none was taken."""
    h = make(f"training.max_policy_lag={MAX_LAG}")
    learner, actor = Learner(), Actor(delay=2)
    before: list[int] = []
    run_cycles(h, learner, actor, at_cycle, before)
    check(before, what="before the restart")
    surplus = len(actor.stored) // EPISODES_PER_CYCLE - learner.checkpoint[0]
    after: list[int] = []
    if how in ("whole-run", "learner"):
        learner.restart(2)
        actor.seen.append(learner.version)  # the restarted learner's weights reach the actor
    if how in ("whole-run", "replay"):
        if actor.waiting is not None and not actor.waiting[0].results:
            actor.waiting = None  # its query died with the replay: it acts a new one
            actor.seq += 1
        h = restarted_replay(actor)
        if learner.waiting is not None:
            learner.waiting = None  # so did the learner's: it asks again
    run_cycles(h, learner, actor, 15, after)
    check(after, what=f"after a {how} restart at cycle {at_cycle} ({surplus} cycles ahead "
                      f"of the learner's checkpoint)")
    if how != "replay" and at_cycle > 5:
        assert surplus > 0, "the case the fix is for: episodes acted after the checkpoint"


def test_the_bound_holds_from_the_first_insert_after_a_replay_restart() -> None:
    """Before the learner's first call to a restarted replay, an episode acted with weights
    far older than those the log's episodes were acted with is refused: the recovered
    episodes' newest version stands for the learner's until it asks."""
    h = make(f"training.max_policy_lag={MAX_LAG}")
    learner, actor = Learner(), Actor(delay=1)
    run_cycles(h, learner, actor, 10, [])
    h = restarted_replay(actor)
    stale = h.episode(10_000)
    stale.policy_version = 0  # an actor restarted with its initial policy
    waiter = Recorder("stale", h.journal)
    h.table.insert(stale, record=pb.Episode(seq=10_000), waiter=waiter)
    assert waiter.failures and waiter.failures[0][0] == Reason.STALE_POLICY
    assert "max_policy_lag=3" in waiter.failures[0][1]


def test_a_free_running_learner_behind_its_data_reads_as_lag() -> None:
    """Without the limiter nothing ties the learner to the inserts: the log holds 1,053 cycles
    of episodes and the learner resumes at version 1,000 and does not redo them, so an episode
    acted with version 995 and stored in cycle 1,053 is 58 cycles staler than lockstep."""
    h = make("replay.free_run=true")
    h.table.recover([(i, h.episode(i)) for i in range(4212)])
    h.sample(8, version=1000)
    for seq in range(8):  # ids 4212..4219: cycle 1053 and 1054
        episode = h.episode(10_000 + seq)
        episode.policy_version = 995
        h.table.insert(episode, record=pb.Episode(), waiter=Recorder(str(seq), h.journal))
    got = h.sample(8, version=1001).results[0]
    assert got.policy_lags.tolist() == [i // 4 - 995 for i in range(4212, 4220)]
