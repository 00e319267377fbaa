"""Task specifications for the gymnasium-robotics Fetch environments, and their reward.

The replay never holds an environment (docs/DESIGN.md §10): everything it needs about a task, the
array shapes and the vectorised reward, lives here. `fetch_reward` is tested to agree with
`env.unwrapped.compute_reward` on real environments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hercs.errors import ConfigError


@dataclass(frozen=True)
class TaskSpec:
    """Shapes and constants of one Fetch task (all Fetch*-v4 tasks share T=50, 4-d actions)."""

    name: str
    env_id: str
    obs_dim: int
    goal_dim: int = 3
    action_dim: int = 4
    episode_steps: int = 50
    max_action: float = 1.0
    distance_threshold: float = 0.05
    has_object: bool = True
    """The observation carries an object's position at obs[3:6] (all but Reach)."""

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        return fetch_reward(achieved_goal, desired_goal, self.distance_threshold)

    def is_success(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        """Success as the env defines it: goal distance below the threshold."""
        return goal_distance(achieved_goal, desired_goal) < self.distance_threshold


TASKS: dict[str, TaskSpec] = {
    "reach": TaskSpec(name="reach", env_id="FetchReach-v4", obs_dim=10,
                      has_object=False),
    "push": TaskSpec(name="push", env_id="FetchPush-v4", obs_dim=25),
    "pick": TaskSpec(name="pick", env_id="FetchPickAndPlace-v4", obs_dim=25),
    "slide": TaskSpec(name="slide", env_id="FetchSlide-v4", obs_dim=25),
}


def task_spec(name: str) -> TaskSpec:
    try:
        return TASKS[name]
    except KeyError:
        raise ConfigError(
            f"task.name: unknown task {name!r}; expected one of {sorted(TASKS)}"
        ) from None


def goal_distance(achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)


def fetch_reward(
    achieved_goal: np.ndarray, desired_goal: np.ndarray, distance_threshold: float = 0.05
) -> np.ndarray:
    """Sparse reward of the Fetch tasks, vectorised over leading axes: 0 if within the
    threshold, else -1 (float32, like the env's `compute_reward`)."""
    d = goal_distance(achieved_goal, desired_goal)
    return -(d > distance_threshold).astype(np.float32)
