"""HER-CS for Stable-Baselines3: `ClusterHerReplayBuffer`, SB3's `HerReplayBuffer` drawing
episodes as a hercs method does (`pip install 'hercs[sb3]'`).

    from sb3_contrib import TQC
    from hercs.integrations.sb3 import ClusterHerReplayBuffer
    model = TQC("MultiInputPolicy", env, replay_buffer_class=ClusterHerReplayBuffer,
                replay_buffer_kwargs=dict(method="her-cs", n_sampled_goal=4))

SB3 keeps its storage, its HER relabelling (`goal_selection_strategy`, `n_sampled_goal`) and its
save/load (`model.save_replay_buffer`); only the choice of transitions changes: an episode by
the method's rule, with the k-means model refitted on failed desired goals as the paper does
(`hercs.integrations.clustered_episodes`), then one of its steps uniformly.

Importing it registers gymnasium-robotics' envs as hercs does (`hercs.rl.envs.register_envs`:
`gymnasium.make("FetchPush-v4")` then works where `make mujoco-py` installed mujoco-py too).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.type_aliases import DictReplayBufferSamples
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from hercs.clusterer.clusterer_core import GoalSuccess
from hercs.config import ClusterConfig, EnergyConfig
from hercs.errors import ConfigError
from hercs.integrations.clustered_episodes import ClusteredEpisodeIndex
from hercs.rl.envs import register_envs

__all__ = ["ClusterHerReplayBuffer", "success_rate"]

register_envs()


class ClusterHerReplayBuffer(HerReplayBuffer):
    """SB3's `HerReplayBuffer`, its transitions drawn by a hercs method (`method`: her,
    her-cs, her-ebp or her-ebp-cs; HER-CS by default).

    `cluster` / `energy`: hercs' `ClusterConfig` / `EnergyConfig` (the paper's defaults: k 8,
    150 failed goals a refit). An episode failed unless its last info's `success_key` is truthy;
    envs without that flag pass `is_success(final_achieved_goal, desired_goal)` (a module-level
    function, so that the buffer pickles). `seed` None: drawn from NumPy's global generator,
    which SB3 seeds from the model's `seed`.
    """

    def __init__(self, buffer_size: int, observation_space: spaces.Dict,
                 action_space: spaces.Space, env: VecEnv, device: th.device | str = "auto",
                 n_envs: int = 1, optimize_memory_usage: bool = False,
                 handle_timeout_termination: bool = True, n_sampled_goal: int = 4,
                 goal_selection_strategy: Any = "future", copy_info_dict: bool = False, *,
                 method: str = "her-cs", cluster: ClusterConfig | None = None,
                 energy: EnergyConfig | None = None, energy_kind: str = "points",
                 success_key: str = "is_success", is_success: GoalSuccess | None = None,
                 seed: int | None = None) -> None:
        super().__init__(buffer_size, observation_space, action_space, env, device=device,
                         n_envs=n_envs, optimize_memory_usage=optimize_memory_usage,
                         handle_timeout_termination=handle_timeout_termination,
                         n_sampled_goal=n_sampled_goal,
                         goal_selection_strategy=goal_selection_strategy,
                         copy_info_dict=copy_info_dict)
        goal_shape = observation_space["achieved_goal"].shape or ()
        if len(goal_shape) != 1:
            raise ConfigError(f"ClusterHerReplayBuffer: achieved_goal has shape {goal_shape}; "
                              "k-means needs flat (goal_dim,) goals")
        self.success_key = success_key
        self.episodes = ClusteredEpisodeIndex(
            capacity=self.buffer_size, n_envs=self.n_envs, goal_dim=int(goal_shape[0]),
            seed=int(np.random.randint(2**31)) if seed is None else int(seed), method=method,
            cluster=cluster, energy=energy, energy_kind=energy_kind, is_success=is_success)

    def add(self, obs: dict[str, np.ndarray], next_obs: dict[str, np.ndarray],  # type: ignore[override]
            action: np.ndarray, reward: np.ndarray, done: np.ndarray,
            infos: list[dict[str, Any]]) -> None:
        self.episodes.overwrite(self.pos)
        starts = self._current_ep_start.copy()
        super().add(obs, next_obs, action, reward, done, infos)
        for env_idx in np.flatnonzero(done):
            flag = infos[env_idx].get(self.success_key)
            self._end_episode(int(env_idx), int(starts[env_idx]),
                              None if flag is None else bool(flag))

    def truncate_last_trajectory(self) -> None:
        """SB3's truncation after a load, and the truncated episodes join the index (their
        outcome unknown: not counted as failures unless `is_success` can judge them)."""
        unfinished = np.flatnonzero(self._current_ep_start != self.pos)
        starts = self._current_ep_start.copy()
        super().truncate_last_trajectory()
        for env_idx in unfinished:
            self._end_episode(int(env_idx), int(starts[env_idx]), None)

    def _end_episode(self, env_idx: int, start: int, succeeded: bool | None) -> None:
        length = int(self.ep_length[start, env_idx])
        steps = (start + np.arange(length)) % self.buffer_size
        ag = np.concatenate([self.observations["achieved_goal"][steps, env_idx],
                             self.next_observations["achieved_goal"][steps[-1:], env_idx]])
        goal = self.observations["desired_goal"][steps[-1], env_idx]
        self.episodes.end_episode(env=env_idx, start=start, achieved_goals=ag, desired_goal=goal,
                                  succeeded=succeeded)

    def sample(self, batch_size: int,  # type: ignore[override]
               env: VecNormalize | None = None) -> DictReplayBufferSamples:
        if not self.episodes.episodes:
            raise RuntimeError("ClusterHerReplayBuffer: no episode has ended yet, so none can be "
                               "drawn; set learning_starts above the episode length")
        positions, envs = self.episodes.draw(batch_size)
        relabelled = int(self.her_ratio * batch_size)
        virtual = self._get_virtual_samples(positions[:relabelled], envs[:relabelled], env)
        real = self._get_real_samples(positions[relabelled:], envs[relabelled:], env)
        return DictReplayBufferSamples(
            observations={key: th.cat((real.observations[key], virtual.observations[key]))
                          for key in virtual.observations},
            actions=th.cat((real.actions, virtual.actions)),
            next_observations={key: th.cat((real.next_observations[key],
                                            virtual.next_observations[key]))
                               for key in virtual.next_observations},
            dones=th.cat((real.dones, virtual.dones)),
            rewards=th.cat((real.rewards, virtual.rewards)))


def success_rate(model: BaseAlgorithm, env_id: str, episodes: int, seed: int) -> float:
    """The share of `episodes` deterministic episodes of a fresh `env_id` (seeded `seed`) whose
    last info says `is_success`; observations normalised as the model trained on them where
    its env is a `VecNormalize`."""
    env: VecEnv = make_vec_env(env_id, n_envs=1, seed=seed)
    trained = model.get_env()
    if isinstance(trained, VecNormalize):
        env = VecNormalize(env, training=False, norm_reward=False)
        env.obs_rms = trained.obs_rms
    obs, outcomes = env.reset(), list[float]()
    while len(outcomes) < episodes:
        action, _ = model.predict(obs, deterministic=True)  # type: ignore[arg-type]
        obs, _, done, infos = env.step(action)
        if done[0]:
            outcomes.append(float(infos[0]["is_success"]))
    return float(np.mean(outcomes))
