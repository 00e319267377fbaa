"""Tasks beyond Fetch: the built-in specs agree with the real environments (shapes, horizon,
action bounds, rewards and success on random goal pairs); any goal environment is read from
itself, and one without the goal interface is refused with what it lacks."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.config import HercsConfig, apply_overrides
from hercs.errors import ConfigError
from hercs.rl.envs import make_env
from hercs.rl.task_registry import task_spec
from tests.support import reset_and_check_spec

pytestmark = pytest.mark.usefixtures("trusted_test_envs")

BUILT_IN_IDS = ["PointMaze_UMaze-v3", "PointMaze_Medium-v3", "HandReach-v3",
                "HandManipulateBlock-v1", "HandManipulateEgg-v1", "HandManipulatePen-v1"]


def _pairs(spec, obs: dict, n: int, rng: np.random.Generator, scale: float):  # type: ignore[no-untyped-def]
    """Goal pairs near the env's own goals, about half within the success threshold."""
    g = np.repeat(np.asarray(obs["desired_goal"], np.float64)[None], n, axis=0)
    ag = g + rng.normal(scale=scale, size=g.shape)
    if spec.family == "hand_manipulate":  # rotations about 0.1 rad apart, unit quaternions
        ag[:, 3:] = g[:, 3:] + rng.normal(scale=0.03, size=(n, 4))
        ag[:, 3:] /= np.linalg.norm(ag[:, 3:], axis=1, keepdims=True)
    return ag, g


@pytest.mark.parametrize("env_id", BUILT_IN_IDS)
def test_built_in_spec_matches_the_env_and_its_reward(env_id: str) -> None:
    spec = task_spec(env_id)
    env = make_env(spec)
    try:
        obs = reset_and_check_spec(spec, env)
        assert np.all(env.action_space.high == spec.max_action)
        assert np.all(env.action_space.low == -spec.max_action)
        rng = np.random.default_rng(1)
        # per-coordinate noise that puts about half the pairs within the threshold
        scale = spec.distance_threshold / np.sqrt(min(spec.goal_dim, 3) if
                                                  spec.family != "hand_reach" else spec.goal_dim)
        ag, g = _pairs(spec, obs, 2048, rng, scale)
        # pair by pair: the hand env's batched rule overwrites one row when it drops the pen's
        # z rotation (gymnasium-robotics 1.4.2)
        expected = np.array([env.unwrapped.compute_reward(a, b, {})
                             for a, b in zip(ag, g, strict=True)], np.float32)
        got = spec.compute_reward(ag, g)
        assert got.shape == (2048,) and got.dtype == np.float32
        np.testing.assert_array_equal(got, expected)
        hits = spec.is_success(ag, g)
        assert 0.05 < hits.mean() < 0.95, "the draw must exercise success and failure"
        if spec.family == "pointmaze":
            np.testing.assert_array_equal(hits, np.linalg.norm(ag - g, axis=1) <= 0.45)
        else:
            np.testing.assert_array_equal(hits, [bool(env.unwrapped._is_success(a, b))
                                                 for a, b in zip(ag, g, strict=True)])
        # the step's own info agrees with the spec's rule
        obs, _, _, _, info = env.step(np.zeros(spec.action_dim, np.float32))
        assert bool(info[spec.success_key]) == bool(
            spec.is_success(obs["achieved_goal"], obs["desired_goal"]))
    finally:
        env.close()


def test_a_users_factory_is_read_from_the_env() -> None:
    spec = task_spec("tests.goal_envs:point_on_a_plane")
    assert (spec.obs_dim, spec.goal_dim, spec.action_dim, spec.episode_steps) == (4, 2, 2, 20)
    assert spec.max_action == 1.0 and spec.reward_rule == "env" and spec.energy == "none"
    ag = np.array([[0.0, 0.0], [0.5, 0.5], [0.05, 0.0]])
    g = np.zeros((3, 2))
    np.testing.assert_array_equal(spec.compute_reward(ag, g), [0.0, -1.0, 0.0])
    # no _is_success: success is "the reward of reaching the goal exactly"
    np.testing.assert_array_equal(spec.is_success(ag, g), [True, False, True])
    # leading axes broadcast as the built-in rule's do
    assert spec.compute_reward(np.zeros((2, 5, 2)), np.zeros(2)).shape == (2, 5)


@pytest.mark.parametrize(("name", "lacks"), [
    ("tests.goal_envs:reward_for_one_pair_only", "compute_reward that works on batches"),
    ("tests.goal_envs:no_horizon", "a fixed horizon"),
    ("tests.goal_envs:not_a_goal_env", "a dict observation space"),
    ("CartPole-v1", "a dict observation space"),
])
def test_an_env_without_the_goal_interface_is_refused_with_what_it_lacks(
        name: str, lacks: str) -> None:
    with pytest.raises(ConfigError, match=f"{name} is not a goal environment.*it lacks {lacks}"):
        task_spec(name)


@pytest.mark.parametrize(("name", "says"), [
    ("no_such_package.envs:make", "must be importable in every process"),
    ("tests.goal_envs:no_such_factory", "has no callable 'no_such_factory'"),
    ("NoSuchEnv-v0", "gymnasium cannot make 'NoSuchEnv-v0'"),
    ("not a task", "expected one of"),
])
def test_a_name_that_names_nothing_says_what_to_do(name: str, says: str) -> None:
    with pytest.raises(ConfigError, match=says):
        task_spec(name)


def test_ebp_is_refused_on_a_task_without_an_energy() -> None:
    with pytest.raises(ConfigError, match=r"run\.method.*no trajectory energy"):
        apply_overrides(HercsConfig(), ["task.name=PointMaze_UMaze-v3", "run.method=her-ebp"])
    ok = apply_overrides(HercsConfig(), ["task.name=PointMaze_UMaze-v3", "run.method=her-cs"])
    assert ok.task.spec.goal_dim == 2
    hand = apply_overrides(HercsConfig(), ["task.name=HandReach-v3", "run.method=her-ebp-cs"])
    assert hand.task.spec.energy == "points"


def test_task_episode_steps_sets_the_horizon_of_any_task() -> None:
    config = apply_overrides(HercsConfig(), ["task.name=PointMaze_UMaze-v3",
                                             "task.episode_steps=100"])
    spec = config.task.spec
    assert spec.episode_steps == 100 and config.capacity_episodes == 10_000
    env = make_env(spec)
    assert env.spec is not None and env.spec.max_episode_steps == 100
    env.close()
    factory = task_spec("tests.goal_envs:point_on_a_plane", episode_steps=7)
    env = make_env(factory)
    env.reset(seed=0)
    truncated = [env.step(np.zeros(2, np.float32))[3] for _ in range(7)]
    assert truncated == [False] * 6 + [True]
    with pytest.raises(ConfigError, match=r"task\.episode_steps.*be >= 0"):
        apply_overrides(HercsConfig(), ["task.episode_steps=-1"])
