"""One rollout as plain arrays: what an actor produces and the replay stores.

With T = spec.episode_steps, all float32: obs (T+1, obs_dim) o_0..o_T; ag (T+1, goal_dim) the
achieved goals ag_0..ag_T (Fetch: 3-d); g (T, goal_dim) the desired goal at each step (constant
in Fetch); actions (T, action_dim) u_0..u_{T-1}.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hercs.rl.task_registry import TaskSpec


@dataclass
class EpisodeData:
    obs: np.ndarray
    ag: np.ndarray
    g: np.ndarray
    actions: np.ndarray
    actor_id: str = ""
    seq: int = 0
    success: bool = False
    """The env's `is_success` at the last step."""
    policy_version: int = -1
    """Version of the Weights the actor acted with (-1: initial random policy)."""

    @property
    def final_ag(self) -> np.ndarray:
        return self.ag[-1]

    @property
    def desired_goal(self) -> np.ndarray:
        return self.g[-1]


@dataclass(frozen=True)
class EpisodeIdentity:
    """Who made a batch of episodes, given to them as they are made (`VectorRollout`): the
    actor's wire id, the first episode's seq (the others follow in env order) and the weights
    version they were acted with."""

    actor_id: str
    first_seq: int
    policy_version: int


def expected_shapes(spec: TaskSpec) -> dict[str, tuple[int, ...]]:
    T = spec.episode_steps
    return {
        "obs": (T + 1, spec.obs_dim),
        "ag": (T + 1, spec.goal_dim),
        "g": (T, spec.goal_dim),
        "actions": (T, spec.action_dim),
    }
