"""HER-CS inside Stable-Baselines3 (`hercs.integrations.sb3`), with the real SB3, sb3-contrib
and FetchReach: the buffer's draws keep the share plan, an agent learns with it, and it saves
and loads with the model's replay buffer."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from sb3_contrib import TQC
from stable_baselines3 import SAC
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from hercs.config import ClusterConfig
from hercs.integrations.clustered_episodes import _EpisodeTable
from hercs.integrations.sb3 import ClusterHerReplayBuffer, success_rate
from hercs.rl.samplers.cluster_balanced import plan_shares

SMALL_FGB = ClusterConfig(k=4, fgb_size=12, kmeans_n_init=1)
"""A refit every 12 failed episodes, so that clusters shape the draw within a short test."""


@pytest.fixture(autouse=True)
def one_torch_thread() -> Iterator[None]:
    """SB3 trains in this process: one thread, as each hercs service runs, so that the test's
    speed does not hang on how many other processes share the cores."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _model(algo, n_envs: int, seed: int, normalize: bool = False,  # type: ignore[no-untyped-def]
           **kwargs):
    env = make_vec_env("FetchReach-v4", n_envs=n_envs, seed=seed)
    if normalize:  # rl-zoo's `normalize: True` for FetchReach (the reward left as it is)
        env = VecNormalize(env, norm_reward=False, gamma=0.95)
    return algo("MultiInputPolicy", env, replay_buffer_class=ClusterHerReplayBuffer,
                replay_buffer_kwargs=dict(cluster=SMALL_FGB), buffer_size=100_000,
                gamma=0.95, learning_rate=1e-3, seed=seed, verbose=0, **kwargs)


def test_tqc_with_two_envs_draws_the_share_plan_and_fits_on_its_failures() -> None:
    model = _model(TQC, n_envs=2, seed=3, learning_starts=100, batch_size=128,
                   policy_kwargs=dict(net_arch=[32, 32], n_critics=1))
    model.learn(1200)  # SB3 counts steps of all envs: 24 episodes, 12 in each column
    buffer = model.replay_buffer
    assert isinstance(buffer, ClusterHerReplayBuffer)
    index = buffer.episodes
    assert index.clusterer is not None and index.episodes == 24
    assert set(np.nonzero(index._live)[1]) == {0, 1}
    failures = index.clusterer.failures_seen
    assert index.model is not None and index.model.version == failures // SMALL_FGB.fgb_size
    plan = plan_shares(_EpisodeTable.of(index).sampling_index, k=4, repeat=4, batch_size=256)
    assert plan is not None
    for _ in range(50):
        batch = buffer.sample(256)
        assert batch.actions.shape == (256, 4) and batch.observations["desired_goal"].shape == (
            256, 3)
        assert index.last_draw is not None
        assert (index.last_draw.cluster_counts >= plan.member_draws).all()


@pytest.mark.learning
@pytest.mark.full
def test_sac_learns_fetchreach_with_the_her_cs_buffer() -> None:
    """A bound on learning, not "it ran": with rl-zoo's FetchReach settings (64×64, γ .95,
    lr 1e-3, normalised observations) SB3's own HER buffer and this one, seed 0 each, both
    read success .8–1.0 (10 episodes) from 2,000 steps on, 0 at 1,500 (run side by side on
    this 2-core machine); without the normalisation neither learned in 4,000."""
    model = _model(SAC, n_envs=1, seed=0, normalize=True, learning_starts=500, batch_size=256,
                   policy_kwargs=dict(net_arch=[64, 64]))
    model.learn(3000)
    index = model.replay_buffer.episodes
    assert index.model is not None and index.model.version >= 2  # clusters shaped the draw
    assert success_rate(model, "FetchReach-v4", episodes=20, seed=100) >= 0.8


def test_the_buffer_saves_and_loads_with_its_clusters(tmp_path: Path) -> None:
    model = _model(SAC, n_envs=1, seed=1, learning_starts=100, batch_size=64,
                   policy_kwargs=dict(net_arch=[16]))
    model.learn(735)  # 14 episodes and 35 steps of the 15th: saved mid-episode
    before = model.replay_buffer.episodes
    assert before.model is not None
    path = tmp_path / "buffer.pkl"
    model.save_replay_buffer(path)
    other = _model(SAC, n_envs=1, seed=2, learning_starts=100, batch_size=64,
                   policy_kwargs=dict(net_arch=[16]))
    other.load_replay_buffer(path)  # truncates the unfinished 15th episode, as SB3 does
    after = other.replay_buffer.episodes
    np.testing.assert_array_equal(after.model.centroids, before.model.centroids)
    assert after.model.version == before.model.version
    np.testing.assert_array_equal(after.clusterer.fgb.goals(), before.clusterer.fgb.goals())
    assert after.episodes == before.episodes + 1
    truncated = np.zeros_like(after._live)
    truncated[14 * 50, 0] = True
    np.testing.assert_array_equal(after._live, before._live | truncated)
    np.testing.assert_array_equal(after._label[before._live], before._label[before._live])
    # the generator travels too: the next draw of a buffer that had not truncated is the same
    path.unlink()
    model.replay_buffer.truncate_last_trajectory()
    np.testing.assert_array_equal(model.replay_buffer.episodes.draw(64)[0],
                                  other.replay_buffer.episodes.draw(64)[0])


def test_the_example_runs_in_its_quick_mode(tmp_path: Path) -> None:
    """examples/sb3_tqc_her_cs_push.py (TQC + HER-CS, rl-zoo's FetchPush settings) in its
    quick mode, so that it cannot rot: six episodes of FetchPush-v4, a saved model and buffer."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    saved = tmp_path / "push"
    done = subprocess.run([sys.executable, str(root / "examples" / "sb3_tqc_her_cs_push.py"),
                           "--quick", "--save", str(saved)], capture_output=True, text=True,
                          timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert "FetchPush-v4 her-cs seed 1: 300 steps, 6 episodes in the buffer, 0 k-means fits" in (
        done.stdout)
    assert saved.with_suffix(".zip").is_file() and saved.with_suffix(".buffer.pkl").is_file()
