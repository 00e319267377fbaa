"""ReplayTable in lockstep (cycles alternate exactly) and under the policy-lag bound."""

from __future__ import annotations

import numpy as np

from hercs.reasons import Reason
from hercs.replay_service.lockstep import LockstepAdmission
from hercs.replay_service.table import LOCKSTEP_CLUSTER_WAIT_S
from hercs.rl.cluster_model import ClusterModel
from hercs.wire.served import ServedBatch
from tests.unit.replay_service.table_harness import insert_acted, make


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
    assert h.table.status_at(got.samples_served).policy_lag == 0.0
    # the older measure takes the learner's version from the requests served so far: cycle
    # 1's episodes were stored before request 1 was served, acted with weights newer than
    # that (0 − 1), which reads 0, never below (hercs.replay_service.policy_lag)
    assert h.table.status_at(got.samples_served).policy_lag_request == 0.0
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
    failures = h.table.failures
    assert failures == 4, "random Reach episodes fail: the test needs exactly one refit due"
    assert not request.results, "model v1 is due at the 4th failure"
    model = ClusterModel(version=1, centroids=np.zeros((2, 3), np.float32), n_goals=4,
                         failures_seen=4)
    assert h.table.adopt_cluster_model(model, None)
    assert request.results
    assert h.table.status_at(request.results[0].samples_served).cluster_model_version == 1
    assert isinstance(h.table.admission, LockstepAdmission)
    assert h.table.admission.late_cluster_models == 0

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
    assert retry.results
    assert h.table.status_at(retry.results[0].samples_served).cluster_model_version == 1
    assert h.table.admission.late_cluster_models == 1
    request2 = h.sample(8, "cycle 2", version=2)
    for seq in range(8, 12):
        insert_acted(h, seq, 2)
    assert request2.results, "the refit given up on is not waited for again"
    assert h.table.admission.late_cluster_models == 1


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
    store = h.table.store
    assert store.size == 4 and sorted(store.episode_id.tolist()) != [11, 12, 13, 14]
    again = make(*extra)
    assert again.table.recover((i, h.episode(i)) for i in range(15)) == []
    np.testing.assert_array_equal(again.table.store.episode_id, store.episode_id)


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
