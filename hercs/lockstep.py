"""The lockstep schedule's shared vocabulary (docs/DESIGN.md §9.1): what the replay answers an
episode that lockstep has no use for, and which cycle an episode belongs to.

In lockstep, cycle c is: `episodes_per_cycle` episodes acted with weights version c, then the
learner's `minibatches_per_cycle` updates on a buffer holding them, then version c + 1, as the
reference's single process alternates. Episode number i (its episode id, counting from 0)
therefore belongs to cycle i // episodes_per_cycle.
"""

from __future__ import annotations

from enum import StrEnum


class LockstepReason(StrEnum):
    """Error-reply reasons for an insert that lockstep refuses. The episode is well formed but
    will never be wanted, so the actor drops it (no retry) and waits for newer weights."""

    STALE_POLICY = "stale_policy"
    """Acted with weights older than the cycle the learner is collecting for."""
    CYCLE_FULL = "cycle_full"
    """Its cycle already has its `episodes_per_cycle` episodes (another actor was faster)."""


def schedule_cycle(episode_id: int, episodes_per_cycle: int) -> int:
    """The cycle episode `episode_id` belongs to in the lockstep schedule, which is also the
    weights version it would have been acted with there."""
    return int(episode_id) // int(episodes_per_cycle)
