"""Another library's transition buffer seen as episodes, drawn as a hercs method draws them.

An off-policy library (Stable-Baselines3, …) stores transitions in a ring of `capacity`
positions per env. Its shim tells `ClusteredEpisodeIndex` which position it is about to
overwrite and which episodes have ended; the index keeps each live episode's final achieved
goal, cluster label and trajectory energy, feeds the clusterer's failed-goal buffer and k-means
refits (`hercs.clusterer.Clusterer`), and draws training positions with the method's replay
sampler (`hercs.rl.methods.make_sampler`): an episode by the method's rule (HER-CS's
equal cluster shares, EBP's energies), then a step of it uniformly, as the paper's replay does.
No code of the replay's draw is restated here; the library's own HER relabelling is kept.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hercs.clusterer import Clusterer
from hercs.clusterer.clusterer_core import GoalSuccess
from hercs.config import ClusterConfig, EnergyConfig, HercsConfig
from hercs.errors import ConfigError
from hercs.replay_service.energy import trajectory_energy
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.methods import METHODS, make_sampler
from hercs.rl.samplers import SampleInfo
from hercs.rl.samplers.sampling_index import SamplingIndex


class ClusteredEpisodeIndex:
    """The live episodes of a (capacity × n_envs) transition ring, their clusters and energies.

    Positions are the library's: episode (start, env) covers positions start, start + 1, …
    (mod capacity) of env's column. Not thread-safe (a library's buffer is called by one
    thread). Pickles with the buffer that owns it (its clusterer's `is_success` must pickle).
    """

    def __init__(self, *, capacity: int, n_envs: int, goal_dim: int, seed: int,
                 method: str = "her-cs", cluster: ClusterConfig | None = None,
                 energy: EnergyConfig | None = None, energy_kind: str = "points",
                 is_success: GoalSuccess | None = None) -> None:
        if method not in METHODS:
            raise ConfigError(f"method: got {method!r}, must be one of {list(METHODS)}")
        for name, value in (("capacity", capacity), ("n_envs", n_envs), ("goal_dim", goal_dim)):
            if int(value) < 1:
                raise ConfigError(f"ClusteredEpisodeIndex {name}: got {value!r}, must be >= 1")
        config = dataclasses.replace(HercsConfig(), cluster=cluster or ClusterConfig(),
                                     energy=energy or EnergyConfig())
        self.method = METHODS[method]
        self.capacity, self.n_envs, self.goal_dim = int(capacity), int(n_envs), int(goal_dim)
        self.energy_config, self.energy_kind = config.energy, energy_kind
        self.sampler = make_sampler(method, config.sampler_settings)
        self.rng = np.random.default_rng(seed)
        self.clusterer = (Clusterer(config=config.cluster, seed=seed, goal_dim=self.goal_dim,
                                    is_success=is_success)
                          if self.method.needs.clusters else None)
        self.model: ClusterModel | None = None
        """The newest k-means fit of the failed goals (None before the first)."""
        shape = (self.capacity, self.n_envs)
        self._start_of = np.full(shape, -1, np.int64)
        """Start of the live episode covering each position, −1 if none."""
        self._live = np.zeros(shape, bool)
        """True at the start position of each live episode."""
        self._length = np.zeros(shape, np.int64)
        self._final_ag = np.zeros((*shape, self.goal_dim), np.float32)
        self._label = np.full(shape, -1, np.int32)
        self._energy = np.zeros(shape, np.float64)
        self._table: _EpisodeTable | None = None
        """The live episodes as the samplers read them; None after a change (rebuilt on draw)."""
        self.last_draw: SampleInfo | None = None
        """What the latest `draw` did, per cluster (the share metric)."""

    @property
    def episodes(self) -> int:
        """Live episodes."""
        return int(self._live.sum())

    def overwrite(self, position: int) -> None:
        """Position `position` of every env is about to be rewritten: the episodes covering it
        leave the index whole, as they leave the library's buffer."""
        for env in range(self.n_envs):
            start = int(self._start_of[position, env])
            if start >= 0:
                span = (start + np.arange(self._length[start, env])) % self.capacity
                self._start_of[span, env] = -1
                self._live[start, env] = False
                self._table = None

    def end_episode(self, *, env: int, start: int, achieved_goals: np.ndarray,
                    desired_goal: np.ndarray, succeeded: bool | None) -> ClusterModel | None:
        """Episode (start, env) ended: its T transitions hold achieved goals ag_0..ag_T
        (`achieved_goals`, (T + 1, goal_dim)) and desired goal g. `succeeded` None: judged by
        the clusterer's `is_success`, or (without one) not counted among the failures.
        Returns the cluster model this episode's failure made, if it made one."""
        ag = np.asarray(achieved_goals, np.float64)
        goal = np.asarray(desired_goal, np.float64)
        length = ag.shape[0] - 1 if ag.ndim == 2 else 0
        if ag.ndim != 2 or ag.shape[1] != self.goal_dim or not 1 <= length <= self.capacity:
            raise ValueError(f"episode ({start}, env {env}): achieved goals of shape {ag.shape},"
                             f" need (T + 1, {self.goal_dim}) with 1 <= T <= {self.capacity}")
        finite = np.isfinite(ag).all() and np.isfinite(goal).all()
        if goal.shape != (self.goal_dim,) or not finite:
            raise ValueError(f"episode ({start}, env {env}): desired goal of shape {goal.shape} "
                             f"or its goals hold NaN/Inf; need finite ({self.goal_dim},) goals")
        span = (start + np.arange(length)) % self.capacity
        self._start_of[span, env] = start
        self._live[start, env] = True
        self._length[start, env] = length
        self._final_ag[start, env] = ag[-1]
        if self.method.needs.energy:
            self._energy[start, env] = float(
                trajectory_energy(ag, self.energy_config, self.energy_kind))
        self._label[start, env] = -1 if self.model is None else self.model.assign(ag[-1:])[0]
        self._table = None
        return self._observe(ag[-1], goal, succeeded)

    def _observe(self, final_ag: np.ndarray, goal: np.ndarray,
                 succeeded: bool | None) -> ClusterModel | None:
        if self.clusterer is None or (succeeded is None and self.clusterer.is_success is None):
            return None
        model = self.clusterer.observe(final_ag=final_ag, desired_goal=goal, succeeded=succeeded)
        if model is not None:
            self.model = model
            starts = np.nonzero(self._live)
            self._label[starts] = model.assign(self._final_ag[starts])
        return model

    def draw(self, batch_size: int) -> tuple[np.ndarray, np.ndarray]:
        """(positions, envs) of `batch_size` transitions, in random order: episodes by the
        method's sampler, a step of each uniformly."""
        table = self._table = self._table or _EpisodeTable.of(self)
        slots, self.last_draw = self.sampler.sample(table, batch_size, self.rng)
        order = self.rng.permutation(batch_size)  # the sampler lists draws cluster by cluster
        starts, envs = table.starts[slots[order]], table.envs[slots[order]]
        steps = (self.rng.random(batch_size) * self._length[starts, envs]).astype(np.int64)
        return (starts + steps) % self.capacity, envs

    def episode_labels(self, positions: np.ndarray, envs: np.ndarray) -> np.ndarray:
        """The cluster label (−1: none) of the episode each (position, env) belongs to."""
        starts = self._start_of[positions, envs]
        if (starts < 0).any():
            raise ValueError("episode_labels: a position outside every live episode")
        return self._label[starts, envs]


class _EpisodeTable:
    """The live episodes in a fixed order, as `hercs.rl.samplers` read a store."""

    def __init__(self, starts: np.ndarray, envs: np.ndarray, labels: np.ndarray,
                 energy: np.ndarray) -> None:
        self.starts, self.envs = starts, envs
        self.cluster, self.energy = labels, energy
        self.size = int(starts.size)
        self.sampling_index = SamplingIndex(max(self.size, 1))
        self.sampling_index.rebuild(energy, labels)

    @classmethod
    def of(cls, index: ClusteredEpisodeIndex) -> _EpisodeTable:
        starts, envs = np.nonzero(index._live)
        return cls(starts.astype(np.int64), envs.astype(np.int64),
                   index._label[starts, envs].astype(np.int32), index._energy[starts, envs])
