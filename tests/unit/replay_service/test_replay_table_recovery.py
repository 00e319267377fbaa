"""ReplayTable recovery: restarts of the replay and of the learner, the clusterer's snapshot,
group commit while an append is held open."""

from __future__ import annotations

import threading

import numpy as np

from hercs.config import HercsConfig, apply_overrides
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.builder import ReplayBuilder
from hercs.replay_service.table import Stored
from tests.support import Clock
from tests.unit.replay_service.table_harness import (
    OVERRIDES,
    FakeLog,
    Harness,
    Recorder,
    make,
)


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
        h.table.store.episode(i) for i in range(20))])
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
    table = ReplayBuilder(config).table(rng=np.random.default_rng(0), log=log, clock=Clock())
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
