"""Policy: deterministic acting, the reference exploration's statistics, batching, and the
weights round trip an actor does on every broadcast."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from hercs.config import DDPGConfig
from hercs.rl.networks import preprocess
from hercs.rl.normalizer import Normalizer
from hercs.rl.policy import INITIAL_VERSION, Policy
from hercs.rl.task_registry import TaskSpec, task_spec

N = 20_000  # actions per statistical test: the std of a 0.3-frequency estimate is 0.0032


def _spec(max_action: float) -> TaskSpec:
    return dataclasses.replace(task_spec("push"), max_action=max_action)


def _constant_policy(spec: TaskSpec, config: DDPGConfig, value: float) -> Policy:
    """A policy whose μ outputs `value` in every dimension, whatever the input."""
    policy = Policy(spec=spec, config=config, seed=0)
    weights = policy.weights()
    last = max(int(name.split(".")[1]) for name in weights.actor)  # net.<i>.weight
    weights.actor[f"net.{last}.weight"][:] = 0.0
    weights.actor[f"net.{last}.bias"][:] = np.arctanh(value / spec.max_action)
    policy.load(weights)
    return policy


def _inputs(spec: TaskSpec, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, spec.obs_dim)), rng.normal(size=(n, spec.goal_dim))


def test_explore_false_is_deterministic_and_matches_batched() -> None:
    spec = task_spec("push")
    policy = Policy(spec=spec, config=DDPGConfig(), seed=3)
    o, g = _inputs(spec, 5)
    a1 = policy.act(o[0], g[0], explore=False)
    a2 = policy.act(o[0], g[0], explore=False, rng=np.random.default_rng(99))
    assert a1.shape == (spec.action_dim,) and a1.dtype == np.float32
    np.testing.assert_array_equal(a1, a2)
    batched = policy.act(o, g, explore=False)
    assert batched.shape == (5, spec.action_dim)
    for i in range(5):
        np.testing.assert_allclose(batched[i], policy.act(o[i], g[i], explore=False),
                                   rtol=1e-6, atol=1e-7)


def test_explore_true_is_reproducible_from_the_rng() -> None:
    spec = task_spec("push")
    policy = Policy(spec=spec, config=DDPGConfig(), seed=3)
    o, g = _inputs(spec, 8)
    a = policy.act(o, g, explore=True, rng=np.random.default_rng(5))
    b = policy.act(o, g, explore=True, rng=np.random.default_rng(5))
    c = policy.act(o, g, explore=True, rng=np.random.default_rng(6))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_explore_true_without_rng_is_an_error() -> None:
    spec = task_spec("push")
    policy = Policy(spec=spec, config=DDPGConfig(), seed=0)
    o, g = _inputs(spec, 1)
    with pytest.raises(ValueError, match="rng"):
        policy.act(o[0], g[0], explore=True)


@pytest.mark.parametrize("max_action", [1.0, 2.0], ids=["max1", "max2"])
def test_random_action_fraction_is_random_eps(max_action: float) -> None:
    """noise_eps=0: un-replaced actions equal μ exactly; replaced ones are U[±max_action]."""
    spec = _spec(max_action)
    config = DDPGConfig(noise_eps=0.0, random_eps=0.3)
    mu = 0.5 * max_action
    policy = _constant_policy(spec, config, mu)
    o, g = _inputs(spec, N)
    a = policy.act(o, g, explore=True, rng=np.random.default_rng(11))
    kept = np.all(np.abs(a - mu) < 1e-5, axis=1)  # μ to float32 rounding
    assert abs((1 - kept.mean()) - 0.3) < 0.015
    replaced = a[~kept]
    assert np.all(np.abs(replaced) <= max_action)
    # uniform on [−m, m]: mean 0, variance m²/3 (a replaced action is not stuck at μ)
    assert abs(replaced.mean()) < 0.03 * max_action
    assert replaced.var() == pytest.approx(max_action**2 / 3, rel=0.05)


@pytest.mark.parametrize("max_action", [1.0, 2.0], ids=["max1", "max2"])
def test_gaussian_noise_std_is_noise_eps_times_max_action(max_action: float) -> None:
    spec = _spec(max_action)
    config = DDPGConfig(noise_eps=0.2, random_eps=0.0)
    policy = _constant_policy(spec, config, 0.0)
    o, g = _inputs(spec, N)
    a = policy.act(o, g, explore=True, rng=np.random.default_rng(12))
    assert abs(a.mean()) < 0.01 * max_action
    assert a.std() == pytest.approx(0.2 * max_action, rel=0.03)


def test_noise_is_clipped_to_max_action() -> None:
    spec = _spec(1.0)
    config = DDPGConfig(noise_eps=0.2, random_eps=0.0)
    policy = _constant_policy(spec, config, 0.95)
    o, g = _inputs(spec, N)
    a = policy.act(o, g, explore=True, rng=np.random.default_rng(13))
    assert a.max() == np.float32(1.0)  # ~40% of draws exceed 1 before the clip
    assert np.all(np.abs(a) <= 1.0)


def test_weights_round_trip_reproduces_actions() -> None:
    spec = task_spec("push")
    config = DDPGConfig()
    src = Policy(spec=spec, config=config, seed=1)
    o, g = _inputs(spec, 16, seed=4)
    src.o_norm.update(o * 3 + 1)
    src.o_norm.recompute_stats()
    src.g_norm.update(g + 2)
    src.g_norm.recompute_stats()
    w = dataclasses.replace(src.weights(), version=7)
    assert all(isinstance(v, np.ndarray) for v in w.actor.values())

    dst = Policy(spec=spec, config=config, seed=2)
    assert dst.version == INITIAL_VERSION
    assert not np.array_equal(dst.act(o, g, explore=False), src.act(o, g, explore=False))
    dst.load_weights(w.actor, w.o_stats, w.g_stats, w.version)
    assert dst.version == 7
    np.testing.assert_array_equal(dst.act(o, g, explore=False), src.act(o, g, explore=False))


def test_load_weights_rejects_wrong_shapes_and_changes_nothing() -> None:
    spec = task_spec("push")
    policy = Policy(spec=spec, config=DDPGConfig(), seed=1)
    o, g = _inputs(spec, 4)
    before = policy.act(o, g, explore=False)
    w = policy.weights()
    first = next(iter(w.actor))
    w.actor[first] = np.zeros((3, 3), np.float32)
    other_stats = Normalizer(spec.obs_dim)
    other_stats.update(o + 10)
    other_stats.recompute_stats()
    with pytest.raises(ValueError, match=first):
        policy.load_weights(w.actor, other_stats.state_dict(), w.g_stats, 5)
    assert policy.version == INITIAL_VERSION
    np.testing.assert_array_equal(policy.act(o, g, explore=False), before)


def test_numpy_forward_matches_the_torch_actor_before_and_after_new_weights() -> None:
    """Acting evaluates μ with numpy (hercs.rl.networks.NumpyActor); it must be the same μ as the
    torch Actor the learner trains, including right after a weights broadcast."""
    spec = task_spec("push")
    policy = Policy(spec=spec, config=DDPGConfig(), seed=3)
    o, g = _inputs(spec, 64)

    def torch_mu(p: Policy) -> np.ndarray:
        x = preprocess(o, g, p.o_norm, p.g_norm, p.config.clip_obs)
        with torch.no_grad():
            return p.actor(torch.from_numpy(x)).numpy()

    np.testing.assert_allclose(policy.act(o, g, explore=False), torch_mu(policy), atol=1e-6)
    other = Policy(spec=spec, config=DDPGConfig(), seed=4).weights()
    other.version = 7
    policy.load(other)
    acted = policy.act(o, g, explore=False)
    np.testing.assert_allclose(acted, torch_mu(policy), atol=1e-6)
    assert np.abs(acted - Policy(spec=spec, config=DDPGConfig(), seed=3).act(
        o, g, explore=False)).max() > 1e-2  # the new weights are in use
