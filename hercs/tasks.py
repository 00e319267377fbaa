"""Task specifications for the gymnasium-robotics Fetch environments, and their reward.

The replay never holds an environment (docs/DESIGN.md §10): everything it needs about a task, the
array shapes and the vectorised reward, lives here. `fetch_reward` is tested to agree with
`env.unwrapped.compute_reward` on real environments.

Each task exists in two environment versions with the same shapes, horizon and reward
(`ENV_VERSIONS`): `Fetch*-v4` on MuJoCo 3 (the default) and the authors' `Fetch*-v1` on
mujoco-py and MuJoCo 2.1 (`make mujoco-py` installs it).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from hercs.errors import ConfigError

ENV_VERSIONS: dict[str, str] = {
    "v4": "gymnasium-robotics Fetch*-v4 on MuJoCo 3 (the mujoco bindings)",
    "v1": "the authors' Fetch*-v1 on mujoco-py and MuJoCo 2.1 (`make mujoco-py`)",
}
"""Environment versions a task runs on, the default first."""


@dataclass(frozen=True)
class TaskSpec:
    """Shapes and constants of one Fetch task (every Fetch task, v1 or v4, has T=50 and 4-d
    actions; v1 and v4 of a task share every field here but the version)."""

    name: str
    env_name: str
    """gymnasium id without the version, e.g. FetchPush."""
    obs_dim: int
    goal_dim: int = 3
    action_dim: int = 4
    episode_steps: int = 50
    max_action: float = 1.0
    distance_threshold: float = 0.05
    has_object: bool = True
    """The observation carries an object's position at obs[3:6] (all but Reach)."""
    env_version: str = "v4"
    """One of ENV_VERSIONS."""
    weld_torquescale: float = 1.0
    """v4 only: the torquescale of the mocap weld that moves the gripper (MuJoCo 3's
    default 1; `task.weld_torquescale`)."""

    @property
    def env_id(self) -> str:
        """The gymnasium id every env factory makes, e.g. FetchPush-v4."""
        return f"{self.env_name}-{self.env_version}"

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        return fetch_reward(achieved_goal, desired_goal, self.distance_threshold)

    def is_success(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        """Success as the env defines it: goal distance below the threshold."""
        return goal_distance(achieved_goal, desired_goal) < self.distance_threshold


TASKS: dict[str, TaskSpec] = {
    "reach": TaskSpec(name="reach", env_name="FetchReach", obs_dim=10, has_object=False),
    "push": TaskSpec(name="push", env_name="FetchPush", obs_dim=25),
    "pick": TaskSpec(name="pick", env_name="FetchPickAndPlace", obs_dim=25),
    "slide": TaskSpec(name="slide", env_name="FetchSlide", obs_dim=25),
}
"""The tasks on the default environment version (v4)."""


def task_spec(name: str, env_version: str = "v4", weld_torquescale: float = 1.0) -> TaskSpec:
    try:
        spec = TASKS[name]
    except KeyError:
        raise ConfigError(
            f"task.name: unknown task {name!r}; expected one of {sorted(TASKS)}"
        ) from None
    if env_version not in ENV_VERSIONS:
        raise ConfigError(f"task.env_version: got {env_version!r}, must be one of "
                          f"{list(ENV_VERSIONS)}")
    return dataclasses.replace(spec, env_version=env_version, weld_torquescale=weld_torquescale)


def goal_distance(achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)


def fetch_reward(
    achieved_goal: np.ndarray, desired_goal: np.ndarray, distance_threshold: float = 0.05
) -> np.ndarray:
    """Sparse reward of the Fetch tasks, vectorised over leading axes: 0 if within the
    threshold, else -1 (float32, like the env's `compute_reward`)."""
    d = goal_distance(achieved_goal, desired_goal)
    return -(d > distance_threshold).astype(np.float32)
