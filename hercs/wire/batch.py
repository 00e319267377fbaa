"""The one transition batch type: what HER relabelling produces, what a `Minibatch` message
carries (hercs.wire.codec) and what one DDPG update consumes (hercs.learner.ddpg).

Its field list is the single source for all three; the wire carries nothing the learner does
not read (the achieved goals used to compute r stay in the replay).
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np


class TransitionBatch(NamedTuple):
    """B transitions (s_t = [o_t, g], u_t, r_t, s_{t+1} = [o_{t+1}, g]), float32.

    g is the (possibly HER-relabelled) goal of the transition, shared by s_t and s_{t+1}.
    """

    o: np.ndarray
    """(B, obs_dim) observation o_t."""
    g: np.ndarray
    """(B, goal_dim) goal, possibly relabelled."""
    u: np.ndarray
    """(B, action_dim) action u_t."""
    r: np.ndarray
    """(B,) reward r_t = compute_reward(ag_{t+1}, g)."""
    o2: np.ndarray
    """(B, obs_dim) next observation o_{t+1}."""

    @property
    def batch_size(self) -> int:
        return int(self.r.shape[0])


class CheckedBatch(TransitionBatch):
    """A batch already checked against its task (`decode_minibatch`: float32, the task's
    shapes, r as (B,), all finite): the learner takes it as it is. A served batch is built
    once (HER relabelling in the replay) and checked once (on arrival)."""

    __slots__ = ()


TRANSITION_FIELDS: tuple[str, ...] = TransitionBatch._fields
"""("o", "g", "u", "r", "o2"): the codec and the learner's shape checks iterate over it."""


class _Dims(Protocol):
    @property
    def obs_dim(self) -> int: ...
    @property
    def goal_dim(self) -> int: ...
    @property
    def action_dim(self) -> int: ...


def transition_shapes(spec: _Dims, batch_size: int) -> dict[str, tuple[int, ...]]:
    """The one shape table of a `TransitionBatch` of `batch_size` rows for a task: the wire's
    checks (hercs.wire.validation) and the update's (hercs.learner.ddpg) both read it."""
    return {"o": (batch_size, spec.obs_dim), "g": (batch_size, spec.goal_dim),
            "u": (batch_size, spec.action_dim), "r": (batch_size,),
            "o2": (batch_size, spec.obs_dim)}
