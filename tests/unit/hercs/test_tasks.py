"""The vectorised reward agrees with the real environments' compute_reward, on v4 and, where
mujoco-py is installed (`make mujoco-py`), on the authors' v1."""

import numpy as np
import pytest

from hercs.rl.envs import make_env
from hercs.rl.task_registry import ENV_VERSIONS, TASKS, fetch_reward, task_spec
from tests.support import reset_and_check_spec, skip_without_mujoco_py


@pytest.mark.parametrize("version", list(ENV_VERSIONS))
@pytest.mark.parametrize("name", sorted(TASKS))
def test_spec_matches_env_and_reward_agrees(name: str, version: str) -> None:
    if version == "v1":
        skip_without_mujoco_py()
    spec = task_spec(name, version)
    env = make_env(spec)
    try:
        reset_and_check_spec(spec, env)
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


@pytest.mark.parametrize("version", list(ENV_VERSIONS))
def test_stepping_push_gives_the_rewards_and_successes_the_spec_computes(version: str) -> None:
    """A whole FetchPush episode: shapes at every step, the step's reward is the spec's
    reward of the new achieved goal, `is_success` the spec's, and the object moves when the
    gripper is driven through it (so achieved goals are not a constant)."""
    if version == "v1":
        skip_without_mujoco_py()
    spec = task_spec("push", version)
    env = make_env(spec)
    try:
        obs, _ = env.reset(seed=1)
        start = obs["achieved_goal"].copy()
        rewards = []
        for t in range(spec.episode_steps):
            # towards the object, then through it: the gripper is obs[0:3], the object obs[3:6]
            toward = obs["observation"][3:6] - obs["observation"][0:3]
            action = np.append(np.clip(toward * 10 + (t > 15) * 0.3, -1, 1), 0.0)
            obs, reward, terminated, truncated, info = env.step(action.astype(np.float32))
            assert obs["observation"].shape == (spec.obs_dim,)
            assert obs["achieved_goal"].shape == obs["desired_goal"].shape == (spec.goal_dim,)
            assert reward == spec.compute_reward(obs["achieved_goal"], obs["desired_goal"])
            assert bool(info["is_success"]) == bool(
                spec.is_success(obs["achieved_goal"], obs["desired_goal"]))
            assert not terminated and truncated == (t == spec.episode_steps - 1)
            rewards.append(reward)
        assert np.linalg.norm(obs["achieved_goal"] - start) > 0.01, "the object never moved"
        assert set(rewards) <= {0.0, -1.0}
    finally:
        env.close()


def test_reward_is_vectorised_over_leading_axes() -> None:
    ag = np.zeros((2, 5, 3))
    g = np.zeros((2, 5, 3))
    g[1, 2] = [0.0, 0.0, 0.051]
    r = fetch_reward(ag, g)
    assert r.shape == (2, 5) and r[1, 2] == -1.0 and r.sum() == -1.0
