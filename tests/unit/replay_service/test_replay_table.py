"""ReplayTable without any transport: admission order under the rate limiter, parking, dedup of
retries (stored and parked), durable log before the ack, expiry on the caller's timeout,
refusal of requests the limiter could never admit. Recovery: test_replay_table_recovery.py;
lockstep and the lag bound: test_replay_table_lockstep.py."""

from __future__ import annotations

import pytest

from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.table import SampleRefused
from hercs.wire.served import ServedBatch
from tests.unit.replay_service.table_harness import Recorder, make


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


def test_an_admitted_insert_the_store_already_holds_is_refused_before_it_is_logged() -> None:
    """The log records each group under the ids the store gives next; an episode the store
    holds already would get its old id, so the log and the store would disagree. `insert`
    never parks one, so the invariant is broken here by hand: a parked episode is stored
    past its admission (`store_episode`). The whole group is answered, none of it logged, and
    the table goes on with ids that agree."""
    h = make()
    first = [h.insert(seq) for seq in range(10)]  # d reaches 16 after 8: seqs 8, 9 parked
    parked = [*first[8:], h.insert(9, actor="b"), h.insert(8, actor="b")]
    assert not any(w.results or w.failures for w in parked)
    h.table.store_episode(h.episode(8, actor="b"))  # stored as episode 8, never logged
    h.journal.clear()
    h.sample(8)  # d 16 → 8: room for the 4 parked inserts, admitted as one group
    assert [line for line in h.journal if line.startswith("log")] == []
    for waiter in parked:
        ((reason, detail),) = waiter.failures
        assert reason == Reason.INTERNAL and not waiter.results
        assert "episode (actor 'b', seq 8) stored as episode 8: not logged and not stored" \
            in detail
    assert [episode_id for episode_id, _ in h.log.episodes] == list(range(8))
    assert h.table.status().inserts_waiting == 0
    # the actors retry: the new episodes go in under ids the log and the store share
    retried = h.insert(8)
    assert retried.results[0].episode_id == 9 and h.log.episodes[-1][0] == 9
    again = h.insert(8, actor="b")
    assert again.results[0].duplicate and again.results[0].episode_id == 8


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
    assert h.table.status_at(got.samples_served).policy_lag_request == pytest.approx(1.5)
    # against the lockstep schedule (4 episodes per cycle): ids 0–3 belong to cycle 0 (lag
    # 0 − (−1) = 1), ids 4–7 to cycle 1, acted with version 3 (1 − 3 = −2: ahead of the
    # schedule, which reads 0, never below)
    assert h.table.status_at(got.samples_served).policy_lag == pytest.approx(0.5)
