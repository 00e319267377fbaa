"""The lockstep schedule's shared arithmetic (docs/DESIGN.md §9.1): which cycle an episode
belongs to. (What the replay answers an episode lockstep has no use for, `stale_policy` or
`cycle_full`, is in hercs.reasons.)

In lockstep, cycle c is: `episodes_per_cycle` episodes acted with weights version c, then the
learner's `minibatches_per_cycle` updates on a buffer holding them, then version c + 1, as the
reference's single process alternates. Episode number i (its episode id, counting from 0)
therefore belongs to cycle i // episodes_per_cycle.
"""

from __future__ import annotations


def schedule_cycle(episode_id: int, episodes_per_cycle: int) -> int:
    """The cycle episode `episode_id` belongs to in the lockstep schedule, which is also the
    weights version it would have been acted with there."""
    return int(episode_id) // int(episodes_per_cycle)
