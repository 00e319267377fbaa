"""The vectorised reward agrees with the real environments' compute_reward."""

import gymnasium as gym
import gymnasium_robotics
import numpy as np
import pytest

from hercs.tasks import TASKS, fetch_reward, task_spec

gym.register_envs(gymnasium_robotics)


@pytest.mark.parametrize("name", sorted(TASKS))
def test_spec_matches_env_and_reward_agrees(name: str) -> None:
    spec = task_spec(name)
    env = gym.make(spec.env_id)
    try:
        obs, _ = env.reset(seed=0)
        assert obs["observation"].shape == (spec.obs_dim,)
        assert obs["achieved_goal"].shape == obs["desired_goal"].shape == (spec.goal_dim,)
        assert env.action_space.shape == (spec.action_dim,)
        assert env.spec.max_episode_steps == spec.episode_steps
        assert env.unwrapped.distance_threshold == spec.distance_threshold
        assert env.unwrapped.has_object == spec.has_object
        rng = np.random.default_rng(3)
        ag = rng.normal(scale=0.05, size=(4096, 3))
        g = ag + rng.normal(scale=0.04, size=(4096, 3))
        expected = env.unwrapped.compute_reward(ag, g, None)
        got = spec.compute_reward(ag, g)
        assert 0.2 < (got == 0).mean() < 0.9, "the draw must exercise both rewards"
        np.testing.assert_array_equal(got, expected)
        assert got.dtype == np.float32
    finally:
        env.close()


def test_reward_is_vectorised_over_leading_axes() -> None:
    ag = np.zeros((2, 5, 3))
    g = np.zeros((2, 5, 3))
    g[1, 2] = [0.0, 0.0, 0.051]
    r = fetch_reward(ag, g)
    assert r.shape == (2, 5) and r[1, 2] == -1.0 and r.sum() == -1.0
