"""HER future relabelling: draw ranges, relabel fraction, gathers and rewards vs the real env."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.config import HERConfig
from hercs.errors import SamplingError
from hercs.replay_service.her import her_indices, normalizer_sample, relabel, relabel_with_draw
from hercs.replay_service.store import EpisodeStore
from hercs.rl.envs import make_env
from hercs.rl.task_registry import fetch_reward, task_spec
from hercs.wire.batch import TRANSITION_FIELDS
from hercs.wire.episode import EpisodeData

SPEC = task_spec("push")
T = SPEC.episode_steps
FUTURE_P = HERConfig().future_p  # 0.8 for replay_k = 4


def _walk_episode(rng: np.random.Generator, seq: int) -> EpisodeData:
    """The object drifts ~1 cm per step from near the goal, so future goals are sometimes
    within 5 cm of ag_{t+1} (reward 0) and the original goal sometimes is too."""
    start = rng.uniform(-0.1, 0.1, size=3)
    ag = start + np.cumsum(rng.normal(0, 0.01, size=(T + 1, 3)), axis=0)
    g = np.repeat(start[None] + rng.normal(0, 0.05, size=(1, 3)), T, axis=0)
    return EpisodeData(
        obs=rng.standard_normal((T + 1, SPEC.obs_dim)).astype(np.float32),
        ag=ag.astype(np.float32),
        g=g.astype(np.float32),
        actions=rng.uniform(-1, 1, size=(T, SPEC.action_dim)).astype(np.float32),
        seq=seq,
    )


@pytest.fixture(scope="module")
def store() -> EpisodeStore:
    rng = np.random.default_rng(7)
    s = EpisodeStore(capacity_episodes=64, spec=SPEC)
    for i in range(64):
        s.insert(_walk_episode(rng, i))
    return s


@pytest.mark.parametrize("replay_k", [4, 1, 0], ids=["k4-p0.8", "k1-p0.5", "k0-no-her"])
def test_relabel_fraction_is_future_p(store: EpisodeStore, replay_k: int) -> None:
    """Over 100k draws the relabelled fraction is 1 − 1/(1+k) ± 0.01 (σ ≈ 0.0013)."""
    future_p = HERConfig(replay_k=replay_k).future_p
    rng = np.random.default_rng(0)
    idxs = rng.integers(0, store.size, 100_000)
    _, draw = relabel_with_draw(store, idxs, future_p=future_p, reward_fn=SPEC.compute_reward,
                                rng=rng)
    assert abs(draw.her_mask.mean() - future_p) < 0.01


def test_timestep_and_future_index_ranges() -> None:
    """t ∈ [0, T−1] and future_t ∈ [t+1, T], both ends reached; for t = 0 the future index is
    uniform over 1..T (chi-square below its 99.99% point)."""
    draw = her_indices(200_000, T, future_p=FUTURE_P, rng=np.random.default_rng(1))
    assert draw.t.min() == 0 and draw.t.max() == T - 1
    assert np.all(draw.future_t >= draw.t + 1) and np.all(draw.future_t <= T)
    assert np.any(draw.future_t == T)
    at_zero = draw.future_t[draw.t == 0]
    counts = np.bincount(at_zero, minlength=T + 1)[1:]
    expected = at_zero.size / T
    chi2 = float(np.sum((counts - expected) ** 2 / expected))
    assert chi2 < _chi2_9999(T - 1), chi2


def test_batch_gathers_the_right_transition(store: EpisodeStore) -> None:
    """o, u come from (episode, t), o2 from (episode, t+1); g is ag[future_t] where relabelled
    and the episode's own goal elsewhere; r = compute_reward(ag[t+1], g); the store is left
    unchanged."""
    g_before = store.g.copy()
    rng = np.random.default_rng(2)
    idxs = rng.integers(0, store.size, 4096)
    b, draw = relabel_with_draw(store, idxs, future_p=FUTURE_P,
                                reward_fn=SPEC.compute_reward, rng=rng)
    ep, t, m = idxs, draw.t, draw.her_mask
    np.testing.assert_array_equal(b.o, store.obs[ep, t])
    np.testing.assert_array_equal(b.o2, store.obs[ep, t + 1])
    np.testing.assert_array_equal(b.u, store.actions[ep, t])
    np.testing.assert_array_equal(b.g[m], store.ag[ep[m], draw.future_t[m]])
    np.testing.assert_array_equal(b.g[~m], store.g[ep[~m], t[~m]])
    np.testing.assert_array_equal(b.r, fetch_reward(store.ag[ep, t + 1], b.g))
    np.testing.assert_array_equal(store.g, g_before)
    for name in TRANSITION_FIELDS:
        assert getattr(b, name).dtype == np.float32, name
    assert b.r.shape == (4096,) and b.batch_size == 4096


def test_rewards_match_the_real_env_compute_reward(store: EpisodeStore) -> None:
    """r equals FetchPush-v4's vectorised compute_reward(ag2, g) and fetch_reward, exactly,
    on a batch that holds both rewards (so the comparison is not vacuous)."""
    env = make_env(SPEC)
    try:
        rng = np.random.default_rng(3)
        idxs = rng.integers(0, store.size, 4096)
        b, draw = relabel_with_draw(store, idxs, future_p=FUTURE_P,
                                    reward_fn=SPEC.compute_reward, rng=rng)
        ag2 = store.ag[idxs, draw.t + 1]
        env_r = env.unwrapped.compute_reward(ag2, b.g, None)
    finally:
        env.close()
    assert 0.05 < np.mean(b.r == 0) < 0.95
    np.testing.assert_array_equal(b.r, env_r)
    np.testing.assert_array_equal(b.r, fetch_reward(ag2, b.g))


def test_relabel_refuses_out_of_range_slots(store: EpisodeStore) -> None:
    with pytest.raises(SamplingError, match="episode index 64"):
        relabel(store, np.array([0, 64]), future_p=FUTURE_P, reward_fn=SPEC.compute_reward,
                rng=np.random.default_rng(0))


def test_normalizer_sample_draws_one_horizon_of_relabelled_transitions_of_the_episode() -> None:
    """T rows per call; every obs row is one of o_0..o_{T-1}; every g row is the episode's goal
    or one of its achieved goals ag_1..ag_T, relabelled in 0.8 ± 0.02 of 10,000 rows."""
    rng = np.random.default_rng(4)
    ep = _walk_episode(rng, 0)
    relabelled = 0
    calls = 200
    for _ in range(calls):
        obs, g = normalizer_sample(ep, future_p=FUTURE_P, rng=rng)
        assert obs.shape == (T, SPEC.obs_dim) and g.shape == (T, 3)
        obs_rows = (obs[:, None, :] == ep.obs[None, :T, :]).all(-1)
        assert obs_rows.any(axis=1).all()
        is_goal = (g == ep.g[0]).all(-1)
        is_future = (g[:, None, :] == ep.ag[None, 1:, :]).all(-1).any(axis=1)
        assert np.all(is_goal | is_future)
        relabelled += int((~is_goal).sum())
    assert abs(relabelled / (calls * T) - FUTURE_P) < 0.02


def _chi2_9999(df: int) -> float:
    """99.99% point of χ²(df), Wilson–Hilferty approximation (accurate to <1% for df ≥ 10)."""
    z = 3.719
    return df * (1 - 2 / (9 * df) + z * np.sqrt(2 / (9 * df))) ** 3
