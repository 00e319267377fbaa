"""What a task is: `TaskSpec` (shapes, horizon, reward and success rule) and the rules
themselves, vectorised. Which task a name means is `hercs.rl.task_registry`; an environment's own
functions, where a task uses them, come from `hercs.rl.goal_env` (installed as a hook here, so
that this module needs no environment package).
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

ENV_VERSIONS: dict[str, str] = {
    "v4": "gymnasium-robotics Fetch*-v4 on MuJoCo 3 (the mujoco bindings)",
    "v1": "the authors' Fetch*-v1 on mujoco-py and MuJoCo 2.1 (`make mujoco-py`)",
}
"""Environment versions a Fetch task runs on, the default first."""

REWARD_RULES = ("distance", "hand", "env")
"""distance: success iff ‖ag − g‖ is within `distance_threshold`, reward `success_reward`
or `failure_reward` (vectorised here); hand: the hand manipulation tasks' position and
rotation thresholds (vectorised here, `hand_success`); env: the environment's own
`compute_reward`."""

ENERGIES: dict[str, str] = {
    "points": "the achieved goal read as 3-d points (positions of objects or fingertips): "
              "potential and kinetic energy of each, summed",
    "hand": "a 3-d position and a (w, x, y, z) rotation: the position's potential and kinetic "
            "energy plus the EBP reference's rotational term, from Euler-angle rates",
    "none": "no trajectory energy is defined: her-ebp and her-ebp-cs are refused",
}
"""How EBP's trajectory energy reads a task's achieved goals (hercs/replay_service/energy.py)."""


@dataclass(frozen=True)
class TaskSpec:
    """Shapes and constants of one task. Every Fetch task, v1 or v4, has T = 50 and 4-d
    actions; v1 and v4 of a task share every field here but the version."""

    name: str
    """`task.name`: a short Fetch name (push), a gymnasium id or module:factory."""
    env_name: str
    """Fetch: the gymnasium id without the version (FetchPush); otherwise the whole id
    (PointMaze_UMaze-v3), or module:factory for a user's factory."""
    obs_dim: int
    goal_dim: int = 3
    action_dim: int = 4
    episode_steps: int = 50
    max_action: float = 1.0
    distance_threshold: float = 0.05
    has_object: bool = True
    """The observation carries the gripper at obs[0:3] and an object at obs[3:6] (the Fetch
    tasks but Reach); what the scene of a logged episode draws."""
    env_version: str = "v4"
    """Fetch only: one of ENV_VERSIONS."""
    weld_torquescale: float = 1.0
    """Fetch v4 only: the torquescale of the mocap weld that moves the gripper (MuJoCo 3's
    default 1; `task.weld_torquescale`)."""
    family: str = "fetch"
    """fetch, pointmaze, hand_reach, hand_manipulate or custom (read from the env)."""
    reward_rule: str = "distance"
    """One of REWARD_RULES."""
    success_reward: float = 0.0
    failure_reward: float = -1.0
    threshold_inclusive: bool = False
    """distance rule: success iff d <= threshold (PointMaze) instead of d < threshold (the
    reward is `success_reward` iff d <= threshold in both)."""
    success_key: str = "is_success"
    """The key of the step's `info` that says whether the goal is reached."""
    energy: str = "points"
    """One of ENERGIES."""
    rotation_threshold: float = 0.1
    """hand rule: the largest angle (rad) between achieved and desired rotation."""
    target_position: str = "random"
    target_rotation: str = "xyz"
    """hand rule: the env's `target_position` / `target_rotation` ('ignore': not judged)."""
    ignore_z_rotation: bool = False
    """hand rule: the rotation about z is not judged (the pen)."""
    make_kwargs: tuple[tuple[str, Any], ...] = ()
    """Keyword arguments of `gym.make` (or of the factory), as pairs."""
    indexed_reads: bool = True
    """`task.indexed_reads`: `make_env` gives a gymnasium-robotics MuJoCo env its observation
    reads by cached ids (bit-identical)."""
    gripper_position: bool = True
    """obs[0:3] is a position in the world (the Fetch gripper): drawn in scenes."""

    @property
    def env_id(self) -> str:
        """The gymnasium id every env factory makes, e.g. FetchPush-v4 (or module:factory)."""
        if self.family == "fetch":
            return f"{self.env_name}-{self.env_version}"
        return self.env_name

    @property
    def goal_points(self) -> int:
        """How many 3-d positions the goal vector starts with, to draw (0: none). A 2-d goal
        (PointMaze) is one point in the plane z = 0; a hand manipulation goal is a position
        then a rotation; HandReach's is five fingertips."""
        if self.family == "hand_reach":
            return self.goal_dim // 3
        if self.family in ("fetch", "pointmaze", "hand_manipulate"):
            return 1
        return 1 if self.goal_dim in (2, 3) else 0

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        """The reward of reaching `achieved_goal` when `desired_goal` was asked, vectorised
        over leading axes (float32, like the env's `compute_reward`)."""
        if self.reward_rule == "env":
            return env_rule(self).reward(achieved_goal, desired_goal)
        if self.reward_rule == "hand":
            return hand_success(self, achieved_goal, desired_goal).astype(np.float32) - 1.0
        # the envs reward d <= threshold (Fetch: -(d > threshold)), whatever their success says
        reached = goal_distance(achieved_goal, desired_goal) <= self.distance_threshold
        return np.where(reached, np.float32(self.success_reward),
                        np.float32(self.failure_reward)).astype(np.float32)

    def is_success(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        """Success as the env defines it (bool, vectorised over leading axes)."""
        if self.reward_rule == "env":
            return env_rule(self).success(achieved_goal, desired_goal)
        if self.reward_rule == "hand":
            return hand_success(self, achieved_goal, desired_goal)
        d = goal_distance(achieved_goal, desired_goal)
        if self.threshold_inclusive:
            return d <= self.distance_threshold
        return d < self.distance_threshold


class EnvRule:
    """What a `reward_rule="env"` task's reward and success rule need: the functions of one
    environment instance, made once per process and never stepped (`hercs.rl.goal_env`)."""

    def __init__(self, reward: Callable[[np.ndarray, np.ndarray], np.ndarray],
                 success: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> None:
        self.reward = reward
        self.success = success


_ENV_RULE_MAKER: Callable[[TaskSpec], EnvRule] | None = None


def set_env_rule_maker(maker: Callable[[TaskSpec], EnvRule]) -> None:
    """Installed by `hercs.rl.goal_env` (which imports gymnasium); kept out of this module so
    that the Fetch specs need no environment package."""
    global _ENV_RULE_MAKER
    _ENV_RULE_MAKER = maker


@functools.cache
def env_rule(spec: TaskSpec) -> EnvRule:
    """The env functions of a `reward_rule="env"` spec. Such specs come only from
    `hercs.rl.goal_env.inspect_goal_env`, whose import installs the maker."""
    if _ENV_RULE_MAKER is None:
        raise RuntimeError(f"{spec.name}: its rewards come from its environment, but "
                           "hercs.rl.goal_env was never imported in this process")
    return _ENV_RULE_MAKER(spec)


FACTORY = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_]\w*")
"""module:factory — an environment a user's own package makes."""


def hand_success(spec: TaskSpec, achieved_goal: np.ndarray,
                 desired_goal: np.ndarray) -> np.ndarray:
    """The hand manipulation tasks' success, vectorised over leading axes: position within
    `distance_threshold` and rotation within `rotation_threshold` (each unless ignored), the
    rotation compared without its z part for the pen. Equal to the env's `_is_success` on
    one pair; the env's own version mis-handles batches when it drops the z part (it
    overwrites one row of the batch), so the replay uses this one."""
    from gymnasium_robotics.utils import rotations

    a = np.asarray(achieved_goal, np.float64)
    b = np.asarray(desired_goal, np.float64)
    a, b = np.broadcast_arrays(a, b)
    ok = np.ones(a.shape[:-1], bool)
    if spec.target_position != "ignore":
        ok &= np.linalg.norm(a[..., :3] - b[..., :3], axis=-1) < spec.distance_threshold
    if spec.target_rotation != "ignore":
        quat_a, quat_b = a[..., 3:], b[..., 3:]
        if spec.ignore_z_rotation:
            euler_a, euler_b = rotations.quat2euler(quat_a), rotations.quat2euler(quat_b)
            euler_a[..., 2] = euler_b[..., 2]
            quat_a = rotations.euler2quat(euler_a)
        diff = rotations.quat_mul(quat_a, rotations.quat_conjugate(quat_b))
        ok &= 2 * np.arccos(np.clip(diff[..., 0], -1.0, 1.0)) < spec.rotation_threshold
    return ok


def goal_distance(achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)


def fetch_reward(
    achieved_goal: np.ndarray, desired_goal: np.ndarray, distance_threshold: float = 0.05
) -> np.ndarray:
    """Sparse reward of the Fetch tasks, vectorised over leading axes: 0 if within the
    threshold, else -1 (float32, like the env's `compute_reward`)."""
    d = goal_distance(achieved_goal, desired_goal)
    return -(d > distance_threshold).astype(np.float32)
