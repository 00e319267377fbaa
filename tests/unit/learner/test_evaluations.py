"""hercs.learner.evaluations: the pending evaluation requests and the policies kept, driven with a
fake clock (no Zenoh)."""

from __future__ import annotations

from hercs.learner.evaluations import EvalRequests, PolicyKeeper
from hercs.run.rundir import BEST
from tests.support import Clock


def test_an_epoch_is_asked_for_again_once_per_resend_period_until_answered() -> None:
    clock = Clock()
    requests = EvalRequests(resend_s=60.0, clock=clock)
    requests.sent(1, b"w1")
    clock.now += 30
    requests.sent(2, b"w2")
    assert requests.overdue([1, 2]) == []
    clock.now += 30                                  # epoch 1: 60 s since it was sent
    assert requests.overdue([1, 2]) == [(1, b"w1")]
    assert requests.overdue([1, 2]) == [], "asking again restarts its period"
    clock.now += 60
    assert requests.overdue([2, 1]) == [(1, b"w1"), (2, b"w2")], "oldest first"
    assert requests.overdue([]) == [], "only the epochs still pending"
    assert requests.answered(1) == b"w1" and 1 not in requests
    assert requests.answered(1) is None, "a repeated answer"


def test_a_resumed_learner_asks_at_once_for_the_epochs_still_pending() -> None:
    clock = Clock()
    before = EvalRequests(resend_s=60.0, clock=clock)
    before.sent(3, b"w3")
    before.sent(4, b"w4")
    after = EvalRequests(resend_s=60.0, clock=clock)
    after.load_state_dict(before.state_dict(), pending=[4])
    assert 3 not in after and after.overdue([4]) == [(4, b"w4")]


def test_best_is_kept_on_improvement_and_every_nth_epoch_is_kept() -> None:
    keeper = PolicyKeeper(every=10, best_success=None)
    assert keeper.files_for(1, 0.0) == [BEST]
    keeper.saved(BEST, 0.0)
    assert keeper.files_for(2, 0.0) == [], "no improvement"
    assert keeper.files_for(10, 0.5) == ["epoch-0010.pt", BEST]
    keeper.saved("epoch-0010.pt", 0.5)
    assert keeper.best_success == 0.0, "only best.pt's write moves the best"
    assert PolicyKeeper(every=0, best_success=0.9).files_for(10, 0.5) == []
