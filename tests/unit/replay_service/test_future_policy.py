"""An episode from a weights version no learner can have published is refused with a reason of
its own (issue 57): the lag is never negative because such an episode is never stored."""

from __future__ import annotations

import pytest

from hercs.reasons import Disposition, Reason
from tests.unit.replay_service.table_harness import insert_acted, make


def test_a_forged_version_is_refused_counted_and_not_stored() -> None:
    h = make()
    waiter = insert_acted(h, 1, 10**15)
    assert [reason for reason, _ in waiter.failures] == [Reason.FUTURE_POLICY]
    assert "version 1000000000000000" in waiter.failures[0][1]
    assert h.table.rejects[Reason.FUTURE_POLICY] == 1
    assert h.table.store.num_inserted == 0
    assert Reason.FUTURE_POLICY.disposition is Disposition.SUPERSEDED  # dropped, not retried


def test_before_any_request_the_initial_and_next_weights_are_admitted() -> None:
    h = make()
    admitted = [insert_acted(h, seq, version) for seq, version in enumerate((0, 1))]
    assert all(not w.failures for w in admitted)
    assert insert_acted(h, 9, 2).failures[0][0] == Reason.FUTURE_POLICY


@pytest.mark.parametrize("prefetch", [0, 3], ids=["no-prefetch", "prefetch-3"])
def test_a_request_on_arrival_moves_the_newest_version_a_learner_can_have_published(
        prefetch: int) -> None:
    h = make(f"learner.prefetch_depth={prefetch}")
    h.sample(8, version=5, learner="L@1")  # parked: too few episodes to serve yet
    newest = 5 + 1 + prefetch
    assert not insert_acted(h, 1, newest).failures
    assert insert_acted(h, 2, newest + 1).failures[0][0] == Reason.FUTURE_POLICY


def test_a_recovered_log_counts_as_announced() -> None:
    """After a replay restart, the versions its log's episodes were acted with existed."""
    h = make()
    h.table.lags.recovered(40)
    assert not insert_acted(h, 1, 41).failures
    assert insert_acted(h, 2, 42).failures[0][0] == Reason.FUTURE_POLICY


def test_after_a_torn_tail_the_lag_is_taken_from_what_was_stored_and_is_never_negative() -> None:
    """A log cut short restarts the ids below the learner's count: an episode acted with
    the learner's newest weights, stored at an id whose schedule cycle is behind them, reads
    lag 0 (it is the freshest there is), where it read -1.1 and -3.2 (issue 57)."""
    h = make()
    h.table.lags.recovered(5)  # the learner is at version 5; the torn log kept too few
    for seq in range(4):
        assert not insert_acted(h, seq, 5).failures
    served = h.sample(8, version=5, learner="L@2")
    [batch] = served.results
    assert len(batch.policy_lags) == 4 and (batch.policy_lags == 0).all(), batch.policy_lags
    assert h.table.lags.mean_schedule_lag == 0.0 and h.table.lags.mean_request_lag == 0.0
