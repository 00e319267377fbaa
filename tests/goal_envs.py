"""Small goal environments a user could write, for the `module:factory` tests: pure numpy, no
simulator. `tests.goal_envs:point_on_a_plane` has the whole goal interface; the others each
lack one part of it. `reach_with_a_reward_scale_file`'s reward is scaled by a test while a run
trains."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import TimeLimit


class PointOnAPlane(gym.Env):
    """A point moved by its velocity commands towards a goal in [-1, 1]²; sparse reward
    -1 until within 0.1."""

    threshold = 0.1

    def __init__(self, batched_reward: bool = True, goal_offset: float | None = None) -> None:
        """`goal_offset`: goals within this much of the start in each coordinate (a reach),
        else anywhere in [-1, 1]²."""
        box = gym.spaces.Box(-2.0, 2.0, (2,), np.float64)
        self.observation_space = gym.spaces.Dict(
            {"observation": gym.spaces.Box(-2.0, 2.0, (4,), np.float64),
             "achieved_goal": box, "desired_goal": box})
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._batched = batched_reward
        self._offset = goal_offset
        self._pos = np.zeros(2)
        self._vel = np.zeros(2)
        self._goal = np.zeros(2)

    def _obs(self) -> dict[str, np.ndarray]:
        return {"observation": np.concatenate([self._pos, self._vel]),
                "achieved_goal": self._pos.copy(), "desired_goal": self._goal.copy()}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):  # type: ignore[override]
        super().reset(seed=seed)
        self._pos = self.np_random.uniform(-1, 1, 2)
        self._vel = np.zeros(2)
        if self._offset is None:
            self._goal = self.np_random.uniform(-1, 1, 2)
        else:
            self._goal = self._pos + self.np_random.uniform(-self._offset, self._offset, 2)
        return self._obs(), {}

    def step(self, action):  # type: ignore[no-untyped-def]
        self._vel = 0.1 * np.clip(np.asarray(action, np.float64), -1, 1)
        self._pos = np.clip(self._pos + self._vel, -2, 2)
        obs = self._obs()
        reward = float(self.compute_reward(obs["achieved_goal"], self._goal, {}))
        success = float(np.linalg.norm(self._pos - self._goal) < self.threshold)
        return obs, reward, False, False, {"is_success": success}

    def compute_reward(self, achieved_goal, desired_goal, info):  # type: ignore[no-untyped-def]
        if not self._batched and np.ndim(achieved_goal) > 1:
            raise ValueError("one pair at a time")
        d = np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)
        return -(d >= self.threshold).astype(np.float32)


REWARD_SCALE_FILE = "GOAL_ENVS_REWARD_SCALE_FILE"
"""The environment variable that names `reach_with_a_reward_scale_file`'s scale file."""


class RewardScaleFromFile(PointOnAPlane):
    """`PointOnAPlane` whose miss costs the number in the file `$GOAL_ENVS_REWARD_SCALE_FILE`
    names, read at every call (1 while there is no such file): a reward whose scale changes
    while a run trains, as a user's reward with a bug in a branch rarely taken does."""

    def compute_reward(self, achieved_goal, desired_goal, info):  # type: ignore[no-untyped-def]
        path = os.environ.get(REWARD_SCALE_FILE, "")
        scale = float(Path(path).read_text()) if path and Path(path).is_file() else 1.0
        return scale * super().compute_reward(achieved_goal, desired_goal, info)


def reach_with_a_reward_scale_file(**kwargs: Any) -> gym.Env:
    """`reach_on_a_plane` with `RewardScaleFromFile`'s reward."""
    return TimeLimit(RewardScaleFromFile(goal_offset=0.4), max_episode_steps=10)


def point_on_a_plane(**kwargs: Any) -> gym.Env:
    return TimeLimit(PointOnAPlane(), max_episode_steps=20)


def reach_on_a_plane(**kwargs: Any) -> gym.Env:
    """Goals within 0.4 of the start: at most 6 steps at full speed, 10 steps an episode."""
    return TimeLimit(PointOnAPlane(goal_offset=0.4), max_episode_steps=10)


def reward_for_one_pair_only(**kwargs: Any) -> gym.Env:
    return TimeLimit(PointOnAPlane(batched_reward=False), max_episode_steps=20)


def no_horizon(**kwargs: Any) -> gym.Env:
    return PointOnAPlane()


def not_a_goal_env(**kwargs: Any) -> gym.Env:
    return TimeLimit(gym.make("CartPole-v1").unwrapped, max_episode_steps=20)
