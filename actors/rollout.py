"""One Fetch episode with a given policy, as arrays (the pure core of actor and evaluator)."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

from hercs.episode import EpisodeData, expected_shapes
from hercs.tasks import TaskSpec

ActFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(observation, desired goal) -> action, for one step."""


class RolloutWorker:
    """Runs fixed-length episodes of T steps in one env.

    The env is seeded once, at the first reset; later resets continue its own generator, so a
    worker's stream of initial states and goals is reproducible from `seed`.
    """

    def __init__(self, *, spec: TaskSpec, env: gym.Env, seed: int) -> None:
        self.spec = spec
        self.env = env
        self._seed: int | None = seed
        shapes = expected_shapes(spec)
        self._obs = np.empty(shapes["obs"], np.float32)
        self._ag = np.empty(shapes["ag"], np.float32)
        self._g = np.empty(shapes["g"], np.float32)
        self._actions = np.empty(shapes["actions"], np.float32)
        self.env_steps = 0

    def skip(self, episodes: int) -> None:
        """Advance the stream of initial states and goals by `episodes` episodes without
        running them (a Fetch env draws from its generator only on reset), e.g. to evaluate on
        the goals the evaluator used for a later epoch."""
        for _ in range(episodes):
            self.env.reset(seed=self._seed)
            self._seed = None

    def run_episode(self, act: ActFn) -> EpisodeData:
        obs, _ = self.env.reset(seed=self._seed)
        self._seed = None
        info: dict = {}
        for t in range(self.spec.episode_steps):
            self._obs[t] = obs["observation"]
            self._ag[t] = obs["achieved_goal"]
            self._g[t] = obs["desired_goal"]
            action = np.asarray(act(obs["observation"], obs["desired_goal"]), np.float32)
            self._actions[t] = action
            obs, _, _, _, info = self.env.step(action)
        T = self.spec.episode_steps
        self._obs[T] = obs["observation"]
        self._ag[T] = obs["achieved_goal"]
        self.env_steps += T
        return EpisodeData(
            obs=self._obs.copy(),
            ag=self._ag.copy(),
            g=self._g.copy(),
            actions=self._actions.copy(),
            success=bool(info.get("is_success", 0.0)),
        )

    def close(self) -> None:
        self.env.close()
