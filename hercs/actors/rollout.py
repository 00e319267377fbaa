"""Fixed-length episodes with a given policy, as arrays (the pure core of actor and evaluator)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import gymnasium as gym
import numpy as np

from hercs.rl.task_registry import TaskSpec
from hercs.wire.episode import EpisodeData, EpisodeIdentity, expected_shapes

ActFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(observation, desired goal) -> action, for one step; with (n, dim) arrays, n actions."""


class VectorRollout:
    """Runs fixed-length episodes in n envs side by side: one batched `act` call per step for
    all of them (the actor's `actor.envs_per_process`), so the policy's per-call overhead is
    paid once per step instead of n times. Episodes have no early termination (the goal
    interface, hercs.rl.goal_env), so the n envs stay in step from reset to step T.

    Env i is seeded once, with `seeds[i]`, at its first reset; later resets continue its own
    generator, so each env's stream of initial states and goals is reproducible from its seed.
    """

    def __init__(self, *, spec: TaskSpec, envs: Sequence[gym.Env], seeds: Sequence[int]) -> None:
        if not envs or len(envs) != len(seeds):
            raise ValueError(f"VectorRollout: {len(envs)} envs and {len(seeds)} seeds; need "
                             "one seed per env and at least one env")
        self.spec = spec
        self.envs = list(envs)
        self._seeds: list[int | None] = list(seeds)
        n, shapes = len(self.envs), expected_shapes(spec)
        self._obs = np.empty((n, *shapes["obs"]), np.float32)
        self._ag = np.empty((n, *shapes["ag"]), np.float32)
        self._g = np.empty((n, *shapes["g"]), np.float32)
        self._actions = np.empty((n, *shapes["actions"]), np.float32)
        # The policy sees the env's float64 observations, as with `RolloutWorker`, not the
        # float32 copies kept for the episode.
        self._o_now = np.empty((n, spec.obs_dim), np.float64)
        self._g_now = np.empty((n, spec.goal_dim), np.float64)
        self.env_steps = 0

    @property
    def num_envs(self) -> int:
        return len(self.envs)

    def _record(self, i: int, t: int, obs: dict) -> None:
        self._o_now[i] = obs["observation"]
        self._g_now[i] = obs["desired_goal"]
        self._obs[i, t] = obs["observation"]
        self._ag[i, t] = obs["achieved_goal"]
        if t < self.spec.episode_steps:
            self._g[i, t] = obs["desired_goal"]

    def skip(self, episodes: int) -> None:
        """Advance every env's stream of initial states and goals by `episodes` episodes
        without running them (a Fetch env draws from its generator only on reset), e.g. to
        evaluate on the goals the evaluator used for a later epoch."""
        for _ in range(episodes):
            for i, env in enumerate(self.envs):
                env.reset(seed=self._seeds[i])
                self._seeds[i] = None

    def run_episodes(self, act: ActFn,
                     identity: EpisodeIdentity | None = None) -> list[EpisodeData]:
        """One episode per env, in env order; with `identity`, env i's episode is made with
        its actor id, seq `first_seq + i` and policy version (else the defaults: an
        evaluation's episodes go nowhere)."""
        infos: list[dict] = [{} for _ in self.envs]
        for i, env in enumerate(self.envs):
            obs, _ = env.reset(seed=self._seeds[i])
            self._seeds[i] = None
            self._record(i, 0, obs)
        T = self.spec.episode_steps
        for t in range(T):
            actions = np.asarray(act(self._o_now, self._g_now), np.float32)
            self._actions[:, t] = actions
            for i, env in enumerate(self.envs):
                obs, _, _, _, infos[i] = env.step(actions[i])
                self._record(i, t + 1, obs)
        self.env_steps += T * len(self.envs)
        who = identity or EpisodeIdentity(actor_id="", first_seq=0, policy_version=-1)
        return [EpisodeData(obs=self._obs[i].copy(), ag=self._ag[i].copy(), g=self._g[i].copy(),
                            actions=self._actions[i].copy(),
                            success=bool(infos[i].get(self.spec.success_key, 0.0)),
                            actor_id=who.actor_id, seq=who.first_seq + i,
                            policy_version=who.policy_version)
                for i in range(len(self.envs))]

    def close(self) -> None:
        for env in self.envs:
            env.close()


class RolloutWorker:
    """Runs fixed-length episodes of T steps in one env: a `VectorRollout` of one env whose
    policy takes one observation and goal (the evaluator, `hercs eval`)."""

    def __init__(self, *, spec: TaskSpec, env: gym.Env, seed: int) -> None:
        self.spec = spec
        self.env = env
        self._vector = VectorRollout(spec=spec, envs=[env], seeds=[seed])

    @property
    def env_steps(self) -> int:
        return self._vector.env_steps

    def skip(self, episodes: int) -> None:
        """See `VectorRollout.skip`."""
        self._vector.skip(episodes)

    def run_episode(self, act: ActFn) -> EpisodeData:
        """`act` gets one observation and goal, (obs_dim,) and (goal_dim,)."""
        return self._vector.run_episodes(
            lambda o, g: np.asarray(act(o[0], g[0]))[None])[0]

    def close(self) -> None:
        self._vector.close()
