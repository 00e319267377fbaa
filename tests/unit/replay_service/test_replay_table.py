"""ReplayTable without any transport: admission order under the rate limiter, parking, dedup of
retries (stored and parked), durable log before the ack, expiry on the caller's timeout,
refusal of requests the limiter could never admit, recovery."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from hercs.config import HercsConfig, apply_overrides
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.replay_core import ReplayCore
from hercs.replay_service.table import (
    LOCKSTEP_CLUSTER_WAIT_S,
    ReplayTable,
    SampleCall,
    SampleRefused,
    Stored,
)
from hercs.rl.cluster_model import ClusterModel
from hercs.wire.episode import EpisodeData, random_episode
from hercs.wire.served import ServedBatch

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


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


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
    core = ReplayCore(config=config, rng=np.random.default_rng(0))
    return Harness(ReplayTable(config=config, core=core, log=log, clock=clock), log, clock,
                   journal, config)


def test_each_insert_is_logged_before_it_is_acknowledged() -> None:
    h = make()
    waiters = [h.insert(seq) for seq in range(3)]
    assert h.journal == ["log 0", "done insert a/0", "log 1", "done insert a/1", "log 2",
                         "done insert a/2"]
    stored = [w.results[0] for w in waiters]
    assert [s.episode_id for s in stored] == [0, 1, 2] and not any(s.duplicate for s in stored)
    assert h.table.status().size_episodes == 3


def test_samples_wait_for_min_episodes_then_inserts_wait_for_samples() -> None:
    h = make()
    first = h.sample(8, "s1")
    assert not first.results and h.table.status().samples_waiting == 1
    inserts = [h.insert(seq) for seq in range(4)]
    # the 4th insert makes I = N_min and d = 8: the parked request of 8 is served at once
    assert len(first.results) == 1 and len(first.results[0].minibatches) == 8
    assert all(w.results for w in inserts)
    # d = 0 now; inserts are admitted until d + 2 > 16, i.e. 8 more, then held
    more = [h.insert(seq) for seq in range(4, 14)]
    assert [bool(w.results) for w in more] == [True] * 8 + [False] * 2
    st = h.table.status()
    assert (st.inserts_waiting, st.rate_limiter) == (2, "holding-inserts")
    # one request of 8 brings d from 16 to 8: both held inserts go in, oldest first
    h.journal.clear()
    second = h.sample(8, "s2")
    # ... as one group: both logged (one append, one fsync) before either is acknowledged
    assert h.journal == ["done s2", "log 12", "log 13", "done insert a/12", "done insert a/13"]
    assert second.results and all(w.results for w in more)


def test_parked_calls_are_served_oldest_first_on_each_side() -> None:
    h = make()
    for seq in range(4):
        h.insert(seq)
    h.sample(8, "drain")  # d = 0
    waiting = [h.sample(4, f"s{i}") for i in range(3)]
    assert not any(w.results for w in waiting)
    h.journal.clear()
    for seq in range(4, 10):  # each insert adds 2 to d: s0 at d = 4, s1 at 4 again, s2 …
        h.insert(seq)
    served = [line for line in h.journal if line.startswith("done s")]
    assert served == ["done s0", "done s1", "done s2"]


def test_retry_of_a_stored_episode_is_answered_at_once_as_a_duplicate() -> None:
    h = make()
    h.insert(0)
    h.journal.clear()
    again = h.insert(0)
    assert h.journal == ["done insert a/0"], "answered without logging again"
    assert again.results[0].duplicate and again.results[0].episode_id == 0
    assert h.table.status().duplicates == 1 and len(h.log.episodes) == 1
    other = h.insert(0, actor="b")
    assert not other.results[0].duplicate, "(actor_id, seq) is the identity, not seq alone"


def test_retry_of_a_parked_insert_joins_it_and_is_stored_once() -> None:
    h = make()
    for seq in range(12):  # d reaches 16 after 8 inserts: seqs 8..11 are parked
        h.insert(seq)
    assert h.table.status().inserts == 8
    retry = h.insert(8)  # the actor timed out and sent seq 8 again: joins the parked call
    assert not retry.results
    h.sample(8)  # d 16 → 8: room for 4 inserts: seqs 8..11
    assert retry.results[0].duplicate and retry.results[0].episode_id == 8
    ids = [episode_id for episode_id, _ in h.log.episodes]
    assert ids == list(range(12)), "seq 8 logged and stored once"
    st = h.table.status()
    assert (st.inserts, st.duplicates) == (12, 1)


def test_a_failed_log_append_answers_log_failed_and_stores_nothing() -> None:
    h = make()
    h.insert(0)
    h.log.fail_next = 1
    failed = h.insert(1)
    assert failed.failures and failed.failures[0][0] == Reason.LOG_FAILED
    assert "No space left" in failed.failures[0][1]
    st = h.table.status()
    assert (st.size_episodes, st.inserts, h.table.log_failures) == (1, 1, 1)
    retried = h.insert(1)  # space is back: the actor's retry goes in with the next id
    assert retried.results[0].episode_id == 1 and not retried.results[0].duplicate


def test_parked_calls_expire_after_their_callers_timeout_and_the_rest_keep_order() -> None:
    h = make()
    early = h.sample(8, "early", timeout_s=5.0)
    patient = h.sample(8, "patient", timeout_s=60.0)
    h.clock.now += 5.0
    assert h.table.expire() == 1
    assert early.failures[0][0] == Reason.EXPIRED and not early.results
    assert h.table.status().samples_waiting == 1
    for seq in range(4):
        h.insert(seq)
    assert patient.results, "the call behind the expired one is served"
    # a parked insert expires too, and its key is free for the actor's retry
    for seq in range(4, 12):
        h.insert(seq)
    held = h.insert(12, timeout_s=10.0)
    h.clock.now += 10.0
    assert h.table.expire() == 1 and held.failures[0][0] == Reason.EXPIRED
    h.sample(8)
    retry = h.insert(12)
    assert retry.results and not retry.results[0].duplicate


def test_expiring_the_head_of_a_queue_lets_admissible_calls_behind_it_through() -> None:
    h = make()
    for seq in range(4):
        h.insert(seq)
    h.sample(8)  # d = 0
    for seq in range(4, 7):
        h.insert(seq)  # d = 6
    big = h.sample(8, "big", timeout_s=1.0)  # needs d ≥ 8: parked
    small = h.sample(4, "small")  # would fit, but waits behind the older request
    assert not big.results and not small.results
    h.clock.now += 1.0
    h.table.expire()
    assert big.failures and small.results


def test_a_request_the_limiter_could_never_admit_is_refused_at_once() -> None:
    h = make()
    # window 2E = 16, and d never gets above 16 − ρ = 14 for sure: 14 is the largest request
    with pytest.raises(SampleRefused, match="at most 14 minibatches"):
        h.sample(15)
    assert h.table.status().samples_waiting == 0
    for seq in range(7):
        h.insert(seq)
    assert h.sample(14).results, "the largest admissible request is admitted"


def test_free_run_admits_everything() -> None:
    h = make("replay.free_run=true")
    assert h.sample(200).results == [], "still nothing before any episode"
    for seq in range(40):
        assert h.insert(seq).results
    assert h.table.status().samples_waiting == 0


def test_policy_lags_against_the_learners_request_and_the_lockstep_schedule() -> None:
    h = make()
    for seq in range(4):
        h.insert(seq)
    h.sample(8, version=5)
    episodes = [h.episode(seq) for seq in range(4, 8)]
    for i, episode in enumerate(episodes):
        episode.policy_version = 3
        h.table.insert(episode, record=pb.Episode(), waiter=Recorder(f"e{i}", h.journal))
    got = h.sample(8, version=6).results[0]
    assert isinstance(got, ServedBatch)
    # mean over the 8 stored: 4 random episodes (version −1) stored while the learner was at
    # 0 → lag 1 each; 4 at version 3 stored while it was at 5 → lag 2 each
    assert got.status.policy_lag_request == pytest.approx(1.5)
    # against the lockstep schedule (4 episodes per cycle): ids 0–3 belong to cycle 0 (lag
    # 0 − (−1) = 1), ids 4–7 to cycle 1, acted with version 3 (lag 1 − 3 = −2)
    assert got.status.policy_lag == pytest.approx(-0.5)


def test_recovery_restarts_the_limiter_balanced_and_dedups_retries() -> None:
    h = make()
    episodes = [(i, h.episode(i)) for i in range(10)]
    assert h.table.recover(episodes) == []
    st = h.table.status()
    assert (st.size_episodes, st.inserts) == (10, 10)
    assert h.log.episodes == [], "recovered episodes are not logged again"
    # balanced: d = 2·10 − 20 = 0, as if the learner had used all of them
    assert h.table.limiter.surplus == 0
    retry = h.insert(3)
    assert retry.results[0].duplicate and retry.results[0].episode_id == 3
    stored = h.insert(10)
    assert isinstance(stored.results[0], Stored) and stored.results[0].episode_id == 10


def test_a_restarted_learner_redoes_its_lost_updates_before_more_inserts() -> None:
    """A learner checkpointed at 16 updates and was killed after 24 were served: its new
    process says it kept 16, so the limiter counts 16 and admits the 8 lost minibatches on the
    episodes already stored, not inserts paid for by updates that were undone. The limiter's
    count stays the learner's real one: 2 updates per stored episode, within the window."""
    h = make()
    for round_ in range(3):  # I = 4, 8, 12 with S = 8, 16, 24
        for seq in range(4 * round_, 4 * round_ + 4):
            assert h.insert(seq).results
        assert h.sample(8, f"old{round_}", learner="L@1", kept=8 * round_).results
    parked = h.sample(8, "old3", learner="L@1", kept=24)  # held: no episodes for it yet
    assert not parked.results and h.table.limiter.samples == 24
    real = 16  # the new process's updates: its checkpoint's
    redo = h.sample(8, "new0", learner="L@2", kept=real)
    assert parked.failures and parked.failures[0][0] == Reason.EXPIRED  # nobody waits for it
    assert redo.results, "the lost updates are redone on the stored episodes"
    real += 8
    assert h.table.limiter.samples == real
    # the 12 stored episodes are owed 24 updates, all done: a further request waits ...
    late = h.sample(8, "new1", learner="L@2", kept=real)
    assert not late.results
    # ... for 4 more episodes, as it would have had the learner never died
    for seq in range(12, 16):
        assert h.insert(seq).results
    assert late.results
    real += 8
    assert h.table.limiter.samples == real == 2 * h.table.status().inserts


def test_a_restarted_replay_takes_the_learners_count() -> None:
    """The replay's samples died with it; the learner's first call after the restart says
    how many its run kept (here 4 fewer than `restart_balanced` guessed)."""
    h = make()
    assert h.table.recover([(i, h.episode(i)) for i in range(10)]) == []
    assert h.table.limiter.samples == 20
    waiter = h.sample(4, learner="L@1", kept=16)
    assert waiter.results and h.table.limiter.samples == 20 and h.table.limiter.surplus == 0


def test_a_learner_that_does_not_say_is_never_resynced() -> None:
    h = make()
    assert h.table.recover([(i, h.episode(i)) for i in range(10)]) == []
    assert h.table.limiter.samples == 20
    # an old learner's call: its samples_kept 0 is not news (a resync to 0 would let it in)
    assert not h.sample(4).results
    assert h.table.limiter.samples == 20


def test_a_reply_the_learner_never_got_is_recounted_at_its_next_call() -> None:
    """The learner gave up on a request (its reply lost): the replay counted 8 it never
    used; its next call says what it kept, and the count follows."""
    h = make()
    for seq in range(12):
        h.insert(seq)
    assert h.sample(8, learner="L@1", kept=0).results
    assert h.sample(8, learner="L@1", kept=8).results  # reply lost on its way
    assert h.table.limiter.samples == 16
    assert h.sample(8, learner="L@1", kept=8).results  # the learner still has only 8
    assert h.table.limiter.samples == 16


def test_a_learner_asking_again_replaces_its_parked_call() -> None:
    """The learner sends one request at a time and asks again when a reply is overdue (a lost
    get): its new call answers the parked one `expired`, so only the call it waits on is
    served, and the limiter counts one batch, not two."""
    h = make()
    for seq in range(4):
        h.insert(seq)
    assert h.sample(8, learner="L@1", kept=0).results
    overdue = h.sample(8, "overdue", learner="L@1", kept=8)  # held: no episodes for it yet
    again = h.sample(8, "again", learner="L@1", kept=8)
    assert overdue.failures and overdue.failures[0][0] == Reason.EXPIRED
    assert "asked again" in overdue.failures[0][1] and not again.results
    for seq in range(4, 8):
        h.insert(seq)
    assert again.results and not overdue.results
    assert h.table.limiter.samples == 16


def test_recovered_surplus_episodes_do_not_read_as_policy_lag() -> None:
    """A resumed asynchronous run: the log holds 4,212 episodes (1,053 cycles) but the learner
    resumes from its checkpoint at weights version 1,000, so 53 cycles of episodes were acted
    after that checkpoint. Against the unshifted schedule every later episode would show 53
    cycles of lag on top of its own; measured from where the learner resumed, it shows its own.
    """
    h = make("replay.free_run=true")
    recovered = [(i, h.episode(i)) for i in range(4212)]
    h.table.recover(recovered)
    early = h.episode(9000)  # stored before the learner's first call: no place yet, no lag
    early.policy_version = 990
    h.table.insert(early, record=pb.Episode(), waiter=Recorder("early", h.journal))
    h.sample(8, version=1000)
    for seq in range(8):  # ids 4213..4220: cycles 1000..1001 once 53 cycles are left out
        episode = h.episode(10_000 + seq)
        episode.policy_version = 995
        h.table.insert(episode, record=pb.Episode(), waiter=Recorder(str(seq), h.journal))
    got = h.sample(8, version=1001).results[0]
    ids = range(4213, 4221)
    assert got.status.policy_lag == pytest.approx(np.mean([(i - 212) // 4 - 995 for i in ids]))
    assert 5 <= got.status.policy_lag <= 6


def test_clusterer_snapshot_holds_the_newest_failed_goals_and_the_counts() -> None:
    h = make("cluster.fgb_size=8", "cluster.k=2", "replay.free_run=true")
    goals = []
    for seq in range(20):
        episode = h.episode(seq)
        if seq % 4 == 0:  # a success: the last achieved goal on the desired goal
            episode.ag[-1] = episode.g[-1]
        else:
            goals.append(episode.g[-1].copy())
        h.table.insert(episode, record=pb.Episode(), waiter=Recorder(str(seq), h.journal))
    snap = h.table.clusterer_state()
    assert (snap.episodes_seen, snap.failures_seen, snap.model_version) == (20, 15, 0)
    np.testing.assert_array_equal(snap.failed_goals, np.array(goals[-8:], np.float32))
    # a restarted replay rebuilds the same snapshot from its log
    again = make("cluster.fgb_size=8", "cluster.k=2")
    again.table.recover([(i, ep) for i, ep in enumerate(
        h.table.core.store.episode(i) for i in range(20))])
    np.testing.assert_array_equal(again.table.clusterer_state().failed_goals, snap.failed_goals)


class HeldLog(FakeLog):
    """A log whose appends can be held open (an fsync that takes its time), from a test."""

    def __init__(self, journal: list[str]) -> None:
        super().__init__(journal)
        self.groups: list[list[int]] = []
        self.hold = threading.Event()  # set: the next append waits for `release`
        self.entered = threading.Event()
        self.release = threading.Event()

    def append_many(self, episodes: list[tuple[int, pb.Episode]]) -> None:
        self.groups.append([episode_id for episode_id, _ in episodes])
        if self.hold.is_set():
            self.hold.clear()
            self.entered.set()
            assert self.release.wait(30), "the test never released the held append"
        super().append_many(episodes)


def test_inserts_arriving_during_an_append_share_the_next_group_and_samples_go_on() -> None:
    """Group commit: while one append is held open (a slow fsync), the table's lock is free
    (a sample is served, three more inserts are admitted and return at once without an ack),
    and the three then go to the log as one group, each acked only after that append."""
    config = apply_overrides(HercsConfig(), [*OVERRIDES, "replay.free_run=true"])
    journal: list[str] = []
    log = HeldLog(journal)
    table = ReplayTable(config=config, core=ReplayCore(config=config,
                                                       rng=np.random.default_rng(0)),
                        log=log, clock=Clock())
    h = Harness(table, log, Clock(), journal, config)
    for seq in range(4):
        h.insert(seq)
    log.hold.set()
    leader = threading.Thread(target=h.insert, args=(4,))
    leader.start()
    assert log.entered.wait(30)
    followers = [h.insert(seq) for seq in (5, 6, 7)]  # return without waiting for the leader
    sampled = h.sample(8, "during the append")
    assert sampled.results and not any(w.results for w in followers)
    assert table.status().size_episodes == 4  # episode 4 is not stored before its fsync
    log.release.set()
    leader.join(30)
    assert not leader.is_alive()
    assert log.groups[-2:] == [[4], [5, 6, 7]]
    assert [w.results[0].episode_id for w in followers] == [5, 6, 7]
    assert journal.index("log 7") < journal.index("done insert a/5")
    assert table.status().size_episodes == 8


# ---------------------------------------------------------------------------------- lockstep

def insert_acted(h: Harness, seq: int, version: int, actor: str = "a") -> Recorder:
    episode = h.episode(seq, actor)
    episode.policy_version = version
    waiter = Recorder(f"insert {actor}/{seq}", h.journal)
    h.table.insert(episode, record=pb.Episode(seq=seq), waiter=waiter)
    return waiter


def test_lockstep_alternates_cycles_exactly_and_refuses_what_it_cannot_use() -> None:
    """4 episodes per cycle, 8 minibatches per cycle: cycle c's request is served once four
    episodes acted with version c are stored; a fifth of version c is `cycle_full`, one acted
    with an older version than the learner asks for is `stale_policy`; each ack says which
    version the actor's next episode needs; the lag against the lockstep schedule is 0."""
    h = make("training.schedule=lockstep")
    early = insert_acted(h, 0, -1)  # acted before the learner's first broadcast
    assert early.failures and early.failures[0][0] == Reason.STALE_POLICY
    request0 = h.sample(8, "cycle 0", version=0)
    acks = [insert_acted(h, seq, 0) for seq in range(1, 5)]
    assert [a.results[0].next_policy_version for a in acks] == [0, 0, 0, 1]
    assert request0.results, "served once its cycle's four episodes are stored"
    assert h.journal.index("done insert a/4") < h.journal.index("done cycle 0")
    surplus = insert_acted(h, 5, 0, actor="b")
    assert surplus.failures[0][0] == Reason.CYCLE_FULL and not surplus.results
    request1 = h.sample(8, "cycle 1", version=1)
    late = insert_acted(h, 6, 0, actor="b")
    assert late.failures[0][0] == Reason.STALE_POLICY
    for seq in range(7, 10):
        insert_acted(h, seq, 1)
    assert not request1.results, "three of cycle 1's four episodes are not enough"
    insert_acted(h, 10, 1, actor="b")
    got = request1.results[0]
    assert isinstance(got, ServedBatch)
    assert got.status.policy_lag == 0.0
    # the older measure takes the learner's version from the requests served so far: cycle
    # 1's episodes were stored before request 1 was served, so they count 0 − 1 = −1
    assert got.status.policy_lag_request == pytest.approx(-0.5)
    status = h.table.status()
    assert (status.inserts, status.rate_limiter) == (8, "lockstep")
    assert status.rejects == {"stale_policy": 2, "cycle_full": 1}


def test_lockstep_waits_for_the_cluster_model_due_or_for_its_grace_time() -> None:
    """HER-CS refits once fgb_size failures have arrived since the last fit, before the next
    update (as the reference's single process): the cycle's request waits until that model is
    adopted, or, if the clusterer is late by more than LOCKSTEP_CLUSTER_WAIT_S since the cycle
    was first asked for (a retried request does not restart the clock), is served with the
    older model and counted; no later cycle waits again for that refit."""
    h = make("training.schedule=lockstep", "run.method=her-cs", "cluster.k=2",
             "cluster.fgb_size=4")
    request = h.sample(8, "cycle 0", version=0)
    for seq in range(4):
        insert_acted(h, seq, 0)
    failures = h.table.core.failures
    assert failures == 4, "random Reach episodes fail: the test needs exactly one refit due"
    assert not request.results, "model v1 is due at the 4th failure"
    model = ClusterModel(version=1, centroids=np.zeros((2, 3), np.float32), n_goals=4,
                         failures_seen=4)
    assert h.table.adopt_cluster_model(model, None)
    assert request.results and request.results[0].status.cluster_model_version == 1
    assert h.table.gate is not None and h.table.gate.late_cluster_models == 0

    first_ask = h.sample(8, "cycle 1", version=1, timeout_s=20)
    for seq in range(4, 8):
        insert_acted(h, seq, 1)  # the 8th failure: model v2 due, no clusterer answers
    assert not first_ask.results
    h.clock.now += 20
    h.table.expire()  # the learner's request times out; it asks again
    assert first_ask.failures and first_ask.failures[0][0] == Reason.EXPIRED
    retry = h.sample(8, "cycle 1 again", version=1)
    h.clock.now += LOCKSTEP_CLUSTER_WAIT_S - 20
    h.table.expire()  # the service's once-a-second tick
    assert retry.results and retry.results[0].status.cluster_model_version == 1
    assert h.table.gate.late_cluster_models == 1
    request2 = h.sample(8, "cycle 2", version=2)
    for seq in range(8, 12):
        insert_acted(h, seq, 2)
    assert request2.results, "the refit given up on is not waited for again"
    assert h.table.gate.late_cluster_models == 1


def test_lockstep_counts_survive_a_replay_restart() -> None:
    """A restarted replay rebuilds the per-version counts from its log: a cycle complete
    before the restart is served at once, and its version's surplus is still refused."""
    h = make("training.schedule=lockstep")
    recovered = []
    for seq in range(6):
        episode = h.episode(seq)
        episode.policy_version = seq // 4  # cycle 0 complete, cycle 1 half
        recovered.append((seq, episode))
    assert h.table.recover(recovered) == []
    assert h.sample(8, "cycle 0 again", version=0).results
    assert insert_acted(h, 6, 0).failures[0][0] == Reason.STALE_POLICY
    request1 = h.sample(8, "cycle 1", version=1)
    insert_acted(h, 7, 1)
    assert not request1.results
    insert_acted(h, 8, 1)
    assert request1.results


def test_a_replay_restarted_from_its_log_rebuilds_a_randomly_evicted_buffer() -> None:
    """`replay.eviction=random`: the slots overwritten come from the run's seed and the
    episode ids, so recovering the log in id order gives the same buffer, slot for slot."""
    extra = ("replay.eviction=random", "replay.buffer_transitions=200", "replay.free_run=true")
    h = make(*extra)
    for seq in range(15):
        h.insert(seq)
    store = h.table.core.store
    assert store.size == 4 and sorted(store.episode_id.tolist()) != [11, 12, 13, 14]
    again = make(*extra)
    assert again.table.recover((i, h.episode(i)) for i in range(15)) == []
    np.testing.assert_array_equal(again.table.core.store.episode_id, store.episode_id)


def test_lockstep_serves_a_restarted_learners_request_past_a_dead_learners() -> None:
    """A learner died with its request for cycle 2 parked, before any actor had version 2; the
    restarted learner asks for cycle 1 again (its checkpoint): that request is served at once,
    not held behind the one that cannot be served."""
    h = make("training.schedule=lockstep")
    for cycle in (0, 1):
        for i in range(4):
            insert_acted(h, 4 * cycle + i, cycle)
    dead = h.sample(8, "dead learner, cycle 2", version=2)
    again = h.sample(8, "restarted learner, cycle 1", version=1)
    assert again.results and not dead.results


# -- the policy-lag bound (training.max_policy_lag, hercs.replay_service.lag_bound) ----------------
# 4 episodes per cycle: episode i lies in cycle i // 4 of the lockstep schedule; its lag is
# that cycle minus the weights version it was acted with.

def test_the_lag_bound_refuses_a_stale_episode_before_storing_it() -> None:
    h = make("training.max_policy_lag=1")
    for seq in range(4):                         # cycle 0, acted with version 0: lag 0
        assert insert_acted(h, seq, 0).results
    h.sample(8, version=1)                       # the learner is at version 1
    for seq in range(4, 8):                      # cycle 1: lag 1 with version 0, allowed
        assert insert_acted(h, seq, 0).results
    stale = insert_acted(h, 8, 0)                # cycle 2 with version 0: lag 2 > 1
    assert stale.failures[0][0] == Reason.STALE_POLICY
    assert "training.max_policy_lag=1" in stale.failures[0][1]
    assert "act with version 1 or newer" in stale.failures[0][1]
    assert not stale.results and len(h.log.episodes) == 8, "neither logged nor stored"
    st = h.table.status()
    assert st.inserts == 8 and st.rejects == {"stale_policy": 1}
    fresh = insert_acted(h, 9, 1)                # the same cycle with version 1: lag 1
    assert fresh.results[0].episode_id == 8
    # the ack tells the actor the oldest version its next episode may use: cycle 2 − 1
    assert fresh.results[0].next_policy_version == 1


def test_the_lag_bound_always_admits_an_episode_acted_with_the_newest_weights() -> None:
    # however far the limiter and prefetch let the cycles run ahead of the weights, an actor
    # with the learner's newest weights is never held back (no deadlock)
    h = make("training.max_policy_lag=1")
    for seq in range(4):
        insert_acted(h, seq, 0)
    h.sample(8, version=1)                       # d = 0
    for seq in range(4, 12):                     # cycles 1 and 2 with version 1: lag 0, 1
        assert insert_acted(h, seq, 1).results
    h.sample(8, version=1)                       # a prefetched batch: still version 1
    newest = insert_acted(h, 12, 1)              # cycle 3 with version 1: lag 2 > 1 ...
    assert newest.results[0].episode_id == 12, "... but no newer weights exist: admitted"
    older = insert_acted(h, 13, 0)               # cycle 3 with version 0: refused
    assert older.failures[0][0] == Reason.STALE_POLICY
    assert newest.results[0].next_policy_version == 1, "never newer than the newest weights"


def test_sample_calls_carry_the_lags_of_the_episodes_stored_since_the_last_call() -> None:
    h = make()
    for seq in range(4):
        insert_acted(h, seq, 0)
    first = h.sample(8, version=0)
    assert first.results[0].policy_lags.tolist() == [0, 0, 0, 0]
    for seq in range(4, 10):                     # cycle 1 (ids 4..7) and cycle 2 (8, 9)
        insert_acted(h, seq, 0)
    second = h.sample(8, version=1)
    assert second.results[0].policy_lags.tolist() == [1, 1, 1, 1, 2, 2]
    third = h.sample(4, version=2)
    assert third.results[0].policy_lags.tolist() == [], "each episode's lag is handed over once"


def test_the_lag_bound_refuses_nothing_before_the_learner_first_asks() -> None:
    # actors act with their own initial policy (-1) until the learner's weights exist
    h = make("training.max_policy_lag=1")
    waiters = [insert_acted(h, seq, -1) for seq in range(8)]   # cycles 0 and 1: lag up to 2
    assert all(w.results for w in waiters) and h.table.status().rejects == {}
    assert {w.results[0].next_policy_version for w in waiters} == {0}, "0: nothing asked"


def test_a_lag_beyond_int64_is_clipped_not_an_error() -> None:
    """A valid episode may carry any int64 weights version; its lag still fits the wire."""
    from hercs.replay_service.policy_lag import INT64_MAX

    h = make()
    for seq in range(4):
        insert_acted(h, seq, -(1 << 63))
    assert h.sample(8).results[0].policy_lags.tolist() == [INT64_MAX] * 4
