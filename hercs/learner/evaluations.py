"""The learner's epoch-end bookkeeping, pure (no Zenoh, an injected clock): which epochs wait
for an evaluation and with which weights, which are overdue to be asked for again, and which
evaluated policies to keep on disk. `hercs.learner.learner_shell` drives it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable

from hercs.run.rundir import BEST, epoch_file


class EvalRequests:
    """Each pending epoch's `Weights` message (evaluate=True) and when it was last sent.

    An epoch whose result has not come within `resend_s` of its last sending (lost while the
    router restarted, an evaluator that died, a resume) is due again; the evaluator answers a
    repeated request from its cache or evaluates."""

    def __init__(self, *, resend_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.resend_s = resend_s
        self.clock = clock
        self._weights: dict[int, bytes] = {}
        self._sent_at: dict[int, float] = {}

    def __contains__(self, epoch: int) -> bool:
        return epoch in self._weights

    def sent(self, epoch: int, weights: bytes) -> None:
        """Epoch `epoch` ended and its weights went out with evaluate=True just now."""
        self._weights[epoch] = weights
        self._sent_at[epoch] = self.clock()

    def overdue(self, pending: Iterable[int]) -> list[tuple[int, bytes]]:
        """The `pending` epochs to ask for again now, oldest first (each counts as sent)."""
        now = self.clock()
        due = []
        for epoch in sorted(pending):
            weights = self._weights.get(epoch)
            if weights is not None and now - self._sent_at.get(epoch, now) >= self.resend_s:
                self._sent_at[epoch] = now
                due.append((epoch, weights))
        return due

    def answered(self, epoch: int) -> bytes | None:
        """Forget epoch `epoch` (its result was recorded); the weights it was asked with."""
        self._sent_at.pop(epoch, None)
        return self._weights.pop(epoch, None)

    def state_dict(self) -> dict[int, bytes]:
        return dict(self._weights)

    def load_state_dict(self, state: dict[int, bytes], *, pending: Iterable[int]) -> None:
        """Continue a checkpoint's requests for the epochs still `pending`; a resumed learner
        asks for each of them again at once (their answers may have been lost with it)."""
        keep = set(pending)
        self._weights = {int(e): bytes(w) for e, w in state.items() if int(e) in keep}
        self._sent_at = dict.fromkeys(self._weights, -math.inf)


class PolicyKeeper:
    """Which evaluated policies go to `checkpoints/`: `best.pt` whenever an epoch beats every
    earlier one, `epoch-NNNN.pt` every `every` epochs (0: none)."""

    def __init__(self, *, every: int, best_success: float | None) -> None:
        self.every = every
        self.best_success = best_success
        """The success rate of the policy in `best.pt` (None: none saved yet)."""

    def files_for(self, epoch: int, success_rate: float) -> list[str]:
        names = [epoch_file(epoch)] if self.every and epoch % self.every == 0 else []
        if self.best_success is None or success_rate > self.best_success:
            names.append(BEST)
        return names

    def saved(self, name: str, success_rate: float) -> None:
        """`name` was written (a failed write keeps the old best)."""
        if name == BEST:
            self.best_success = success_rate
