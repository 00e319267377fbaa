"""HER-CS for TorchRL: `ClusterEpisodeSampler`, a `torchrl.data.Sampler` that draws transitions
as a hercs method does, for `torchrl.data.HERReplayBuffer(sampler=...)` (`pip install
'hercs[torchrl]'`).

    rb = HERReplayBuffer(reward_fn=..., storage=LazyTensorStorage(1_000_000),
                         sampler=ClusterEpisodeSampler(capacity=1_000_000, goal_dim=3))

TorchRL keeps its storage and its relabelling; the sampler only chooses the indices: an episode
by the method's rule (HER-CS's equal shares of the k-means clusters of failed goals, EBP's
energies), then one of its steps uniformly (`hercs.integrations.clustered_episodes`). Like
`HERReplayBuffer`, it reads episodes as contiguous runs of a 1-D storage ended by the done flag.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torchrl.data.replay_buffers.samplers import Sampler
from torchrl.data.replay_buffers.storages import Storage

from hercs.clusterer.clusterer_core import GoalSuccess
from hercs.config import ClusterConfig, EnergyConfig
from hercs.integrations.clustered_episodes import ClusteredEpisodeIndex

__all__ = ["ClusterEpisodeSampler"]

STATE_FILE = "cluster_episode_sampler.pkl"
"""What `dumps(path)` writes in the buffer's checkpoint folder (a pickle: load only your own)."""

Key = str | tuple[str, ...]


class ClusterEpisodeSampler(Sampler):
    """Indices of a 1-D TorchRL storage of `capacity` transitions, drawn by `method` (her,
    her-cs, her-ebp or her-ebp-cs; HER-CS by default).

    Episodes are read from the storage at the first draw after they end: the transitions from
    the one after the previous episode's end up to one whose `done_key` is set. An episode
    failed unless its last transition's `success_key` is set; without that key,
    `is_success(final_achieved_goal, desired_goal)` judges it, and with neither it is drawn but
    not counted among the failures.
    """

    def __init__(self, *, capacity: int, goal_dim: int, method: str = "her-cs",
                 cluster: ClusterConfig | None = None, energy: EnergyConfig | None = None,
                 energy_kind: str = "points", is_success: GoalSuccess | None = None,
                 seed: int = 0, done_key: Key = ("next", "done"),
                 achieved_goal_key: Key = "achieved_goal", goal_key: Key = "desired_goal",
                 success_key: Key = ("next", "is_success")) -> None:
        self._settings = dict(capacity=capacity, n_envs=1, goal_dim=goal_dim, seed=seed,
                              method=method, cluster=cluster, energy=energy,
                              energy_kind=energy_kind, is_success=is_success)
        self.done_key, self.goal_key, self.success_key = done_key, goal_key, success_key
        self.achieved_goal_key = achieved_goal_key
        self._empty()

    def _empty(self) -> None:
        self.episodes = ClusteredEpisodeIndex(**self._settings)  # type: ignore[arg-type]
        self._written: list[int] = []
        """Positions written since the last draw, in order (read at the next draw)."""
        self._episode_start: int | None = 0
        """Where the episode being written began (None: before the oldest surviving write)."""

    def add(self, index: int) -> None:
        self.extend(torch.as_tensor([index]))

    def extend(self, index: torch.Tensor) -> None:
        for position in torch.as_tensor(index).reshape(-1).tolist():
            self.episodes.overwrite(int(position))
            self._written.append(int(position))

    def sample(self, storage: Storage, batch_size: int) -> tuple[torch.Tensor, dict]:
        self._read_ended_episodes(storage)
        if not self.episodes.episodes:
            raise RuntimeError("ClusterEpisodeSampler: no episode has ended yet (no transition "
                               f"with {self.done_key!r} set), so none can be drawn")
        positions, _ = self.episodes.draw(batch_size)
        return torch.as_tensor(positions, dtype=torch.long), {}

    def _sampleable_count(self, storage: Storage, batch_size: int) -> int:
        self._read_ended_episodes(storage)
        return self.episodes.episodes

    def _read_ended_episodes(self, storage: Storage) -> None:
        capacity = self.episodes.capacity
        written, self._written = self._written, []
        if len(written) > capacity:  # the oldest writes are already overwritten
            written, self._episode_start = written[-capacity:], None
        if not written:
            return
        done = storage[torch.as_tensor(written)].get(self.done_key).reshape(-1).bool()
        for end in (written[i] for i in torch.nonzero(done).reshape(-1).tolist()):
            if self._episode_start is not None:
                self._end_episode(storage, self._episode_start, end)
            self._episode_start = (end + 1) % capacity

    def _end_episode(self, storage: Storage, start: int, end: int) -> None:
        length = (end - start) % self.episodes.capacity + 1
        steps = (start + np.arange(length)) % self.episodes.capacity
        episode = storage[torch.as_tensor(steps)]
        next_key = (("next", *self.achieved_goal_key) if isinstance(self.achieved_goal_key, tuple)
                    else ("next", self.achieved_goal_key))
        ag = torch.cat([episode.get(self.achieved_goal_key), episode.get(next_key)[-1:]])
        flag = episode.get(self.success_key, None)
        self.episodes.end_episode(
            env=0, start=start, achieved_goals=ag.detach().cpu().numpy(),
            desired_goal=episode.get(self.goal_key)[-1].detach().cpu().numpy(),
            succeeded=None if flag is None else bool(flag[-1].any()))

    def state_dict(self) -> dict[str, Any]:
        return {"state": pickle.dumps((self.episodes, self._written, self._episode_start))}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.episodes, self._written, self._episode_start = pickle.loads(state_dict["state"])

    def dumps(self, path: str | Path) -> None:
        folder = Path(path)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / STATE_FILE).write_bytes(self.state_dict()["state"])

    def loads(self, path: str | Path) -> None:
        self.load_state_dict({"state": (Path(path) / STATE_FILE).read_bytes()})

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(method={self._settings['method']!r}, "
                f"episodes={self.episodes.episodes})")
