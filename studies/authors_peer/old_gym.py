"""The old `gym` API (0.17, what the authors' code calls) over a gymnasium environment.

`OldGymEnv` turns `gym.make`, `seed`, `reset`, a 4-value `step`, `_max_episode_steps` and
`compute_reward` into gymnasium's calls and nothing more (the seed goes to the next reset, `done`
is `terminated or truncated`); the env comes from hercs' own factory (`Fetch*-v1`: mujoco-py).
"""

from __future__ import annotations

import types
from typing import Any

import gymnasium as gym
import numpy as np


class OldGymEnv:
    """A gymnasium env seen through the gym 0.17 calls the authors' code makes."""

    def __init__(self, env: gym.Env) -> None:
        self.env = env
        self._seed: int | None = None
        steps = env.spec.max_episode_steps if env.spec is not None else None
        if steps is None:
            raise ValueError(f"{env}: no max_episode_steps in its spec; their code needs "
                             "env._max_episode_steps")
        self._max_episode_steps = int(steps)

    @property
    def action_space(self) -> gym.Space:
        return self.env.action_space

    @property
    def observation_space(self) -> gym.Space:
        return self.env.observation_space

    def seed(self, seed: int) -> list[int]:
        """gym 0.17 seeded the env at once; gymnasium seeds at a reset: the next one."""
        self._seed = int(seed)
        return [self._seed]

    def reset(self) -> dict[str, np.ndarray]:
        seed, self._seed = self._seed, None
        obs, _ = self.env.reset(seed=seed)
        return obs

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, float(reward), bool(terminated or truncated), info

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                       info: Any) -> np.ndarray:
        return self.env.unwrapped.compute_reward(achieved_goal, desired_goal, info)

    def close(self) -> None:
        self.env.close()


def gym_module(make_env: Any) -> types.ModuleType:
    """A module that stands for `gym`: `gym.make(name)` is `OldGymEnv(make_env(name))`."""
    module = types.ModuleType("gym", "gym 0.17 calls over gymnasium (studies.authors_peer)")
    module.make = lambda name, **kwargs: OldGymEnv(make_env(name, **kwargs))  # type: ignore[attr-defined]
    return module
