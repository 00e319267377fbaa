"""HER-CS inside TorchRL (`hercs.integrations.torchrl`), with the real TorchRL HERReplayBuffer
and storage: episodes read from the done flags, the share plan's draws, eviction on wrap, and a
checkpoint round trip through the buffer's own dumps/loads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.data import HERReplayBuffer, LazyTensorStorage, TensorDictReplayBuffer

from hercs.config import ClusterConfig
from hercs.integrations.clustered_episodes import _EpisodeTable
from hercs.integrations.torchrl import ClusterEpisodeSampler
from hercs.rl.samplers.cluster_balanced import plan_shares

T = 10
CENTRES = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def _reward(td: TensorDict) -> torch.Tensor:
    distance = (td["next", "achieved_goal"] - td["desired_goal"]).norm(dim=-1, keepdim=True)
    return -(distance > 0.05).float()


def _episode(region: int, generator: torch.Generator) -> TensorDict:
    """T transitions whose achieved goal walks to CENTRES[region]; the goal is never reached."""
    end = CENTRES[region] + 0.01 * torch.randn(3, generator=generator)
    path = torch.stack([end - 0.1 + 0.1 * t / T for t in range(T + 1)])
    goal = (end + 0.5).expand(T, 3)
    done = torch.zeros(T, 1, dtype=torch.bool)
    done[-1] = True
    return TensorDict({
        "observation": torch.randn(T, 6, generator=generator), "achieved_goal": path[:-1],
        "desired_goal": goal, "action": torch.randn(T, 4, generator=generator),
        "next": {"achieved_goal": path[1:], "desired_goal": goal, "reward": -torch.ones(T, 1),
                 "done": done, "is_success": torch.zeros(T, 1, dtype=torch.bool)},
    }, batch_size=[T])


def _buffer(capacity: int, sampler: ClusterEpisodeSampler) -> HERReplayBuffer:
    return HERReplayBuffer(reward_fn=_reward, storage=LazyTensorStorage(capacity),
                           sampler=sampler, batch_size=256)


def test_the_draw_keeps_the_share_plan_and_torchrl_relabels_on_top() -> None:
    generator = torch.Generator().manual_seed(0)
    sampler = ClusterEpisodeSampler(capacity=20_000, goal_dim=3, seed=1,
                                    cluster=ClusterConfig(k=4, fgb_size=20, kmeans_n_init=1))
    rb = _buffer(20_000, sampler)
    regions = np.random.default_rng(0).choice(4, size=200, p=[0.6, 0.25, 0.1, 0.05])
    for region in regions:
        rb.extend(_episode(int(region), generator))
    batch = rb.sample()
    index = sampler.episodes
    assert index.episodes == 200 and index.model is not None and index.model.version == 10
    assert batch["desired_goal"].shape == (256, 3)
    # TorchRL relabelled 80 %: those rows' goals are achieved goals, so some now succeed
    assert (batch["next", "reward"] == 0).float().mean() > 0.05
    plan = plan_shares(_EpisodeTable.of(index).sampling_index, k=4, repeat=4, batch_size=256)
    assert plan is not None
    drawn = np.zeros(4)
    for _ in range(100):
        positions = rb.sample()["index"].numpy()
        labels = index.episode_labels(positions, np.zeros_like(positions))
        counts = np.bincount(labels, minlength=4)
        assert (counts >= plan.member_draws).all()
        drawn += counts
    sizes = np.bincount(index._label[index._live], minlength=4)
    # the smallest cluster (about 5 % of episodes) is drawn far above its size, as HER-CS does
    assert drawn[np.argmin(sizes)] / drawn.sum() > 3 * sizes.min() / sizes.sum()


def test_a_wrapped_storage_evicts_episodes_whole() -> None:
    """Through TorchRL's plain TensorDictReplayBuffer: torchrl 0.14.1's HERReplayBuffer itself
    raises on a wrapped storage written in chunks ("The size of tensor a (3) must match the
    size of tensor b (10)", comparing its cache key's write cursors), whatever the sampler."""
    generator = torch.Generator().manual_seed(1)
    sampler = ClusterEpisodeSampler(capacity=5 * T, goal_dim=3, method="her", seed=0)
    rb = TensorDictReplayBuffer(storage=LazyTensorStorage(5 * T), sampler=sampler,
                                batch_size=2000)
    for region in range(5):  # positions 0..5T-1: full
        rb.extend(_episode(region % 4, generator))
    assert set(rb.sample()["index"].tolist()) == set(range(5 * T))
    rb.extend(_episode(0, generator)[:3])  # 3 steps over the first episode's start
    positions = rb.sample()["index"]
    assert sampler.episodes.episodes == 4
    assert set(positions.tolist()) == set(range(T, 5 * T))  # the first is gone whole


def test_the_sampler_survives_the_buffers_checkpoint(tmp_path: Path) -> None:
    generator = torch.Generator().manual_seed(2)
    sampler = ClusterEpisodeSampler(capacity=2_000, goal_dim=3, seed=3,
                                    cluster=ClusterConfig(k=4, fgb_size=8, kmeans_n_init=1))
    rb = _buffer(2_000, sampler)
    for region in np.arange(30) % 4:
        rb.extend(_episode(int(region), generator))
    rb.sample()
    rb.extend(_episode(1, generator)[:4])  # an unfinished episode at the checkpoint
    rb.dumps(tmp_path)
    other_sampler = ClusterEpisodeSampler(capacity=2_000, goal_dim=3, seed=99,
                                          cluster=ClusterConfig(k=4, fgb_size=8,
                                                                kmeans_n_init=1))
    other = _buffer(2_000, other_sampler)
    other.loads(tmp_path)
    a, b = sampler.episodes, other_sampler.episodes
    assert b.model is not None and a.model is not None
    np.testing.assert_array_equal(a.model.centroids, b.model.centroids)
    for rbuf in (rb, other):  # the unfinished episode's end arrives after the load
        rbuf.extend(_episode(1, generator)[4:])
    np.testing.assert_array_equal(rb.sample()["index"], other.sample()["index"])
    assert a.episodes == b.episodes == 31
