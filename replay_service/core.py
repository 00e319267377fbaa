"""The replay service's core: everything the replay does, with no transport.

`ReplayCore` owns the episode store, the sampler of the configured method, the o/g normalisers,
the current cluster model and the counters that `ReplayStatus` reports. The Zenoh shell
(`replay_service.service`) decodes messages, asks the rate limiter, calls this object and
encodes the answers; tests drive this object directly.

Invariants:
- an (actor_id, seq) pair is stored at most once (`insert` returns `duplicate=True` for a
  retry of a stored episode and changes nothing);
- every stored episode carries the cluster of its last achieved goal under the current model
  (-1 before the first model);
- normaliser statistics cover every stored episode (HER-sampled transitions, as the
  reference's `_update_normalizer`), clipped to ±clip_obs first.
"""

from __future__ import annotations

from collections import Counter, OrderedDict, deque
from dataclasses import dataclass

import numpy as np

from hercs.clustering import ClusterModel
from hercs.config import HercsConfig
from hercs.episode import EpisodeData
from hercs.normalizer import Normalizer, NormalizerState
from hercs.seeding import int_seed
from hercs.served import ServedBatch
from replay_service.energy import trajectory_energy
from replay_service.her import normalizer_sample, relabel
from replay_service.samplers import make_sampler
from replay_service.store import EpisodeStore


@dataclass(frozen=True)
class InsertResult:
    episode_id: int
    duplicate: bool
    energy: float
    cluster: int


class ReplayCore:
    def __init__(self, *, config: HercsConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.spec = config.task.spec
        self.rng = rng
        self.store = EpisodeStore(capacity_episodes=config.capacity_episodes, spec=self.spec,
                                  eviction=config.replay.eviction,
                                  eviction_seed=int_seed(config.run.seed, "replay", "eviction"))
        self.sampler = make_sampler(config.run.method, config)
        d = config.ddpg
        self.o_norm = Normalizer(self.spec.obs_dim, eps=d.norm_eps, clip_range=d.norm_clip)
        self.g_norm = Normalizer(self.spec.goal_dim, eps=d.norm_eps, clip_range=d.norm_clip)
        self.cluster_model: ClusterModel | None = None
        # (actor_id, seq) -> episode id, for the episodes still in the ring.
        self._seen: OrderedDict[tuple[str, int], int] = OrderedDict()
        self.inserts = 0
        self.duplicates = 0
        self.samples = 0
        self.env_steps = 0
        self.rejects: Counter[str] = Counter()
        self.cluster_draws_total = np.zeros(config.cluster.k, np.int64)
        self.failures = 0
        """Inserted episodes that failed (not `TaskSpec.is_success` at their last step)."""
        self.recent_failed_goals: deque[np.ndarray] = deque(maxlen=config.cluster.fgb_size)
        """Desired goals of the newest failed episodes, oldest first: what a restarted
        clusterer refills its failed-goal buffer with."""

    # -- inserts ---------------------------------------------------------------------------
    def lookup(self, actor_id: str, seq: int) -> int | None:
        """Episode id of a stored (actor_id, seq), else None."""
        return self._seen.get((actor_id, seq))

    def insert(self, episode: EpisodeData) -> InsertResult:
        """Store a validated episode unless it is a retry of a stored one."""
        key = (episode.actor_id, int(episode.seq))
        known = self._seen.get(key)
        if known is not None:
            self.duplicates += 1
            slot = self.store.slot_of(known)
            energy = float(self.store.energy[slot]) if slot is not None else 0.0
            cluster = int(self.store.cluster[slot]) if slot is not None else -1
            return InsertResult(known, True, energy, cluster)
        energy = (float(trajectory_energy(episode.ag, self.config.energy, self.spec.energy))
                  if self.spec.energy != "none" else 0.0)
        cluster = -1
        if self.cluster_model is not None:
            cluster = int(self.cluster_model.assign(episode.ag[-1:])[0])
        episode_id = self.store.insert(episode, energy=energy, cluster=cluster)
        self._remember(key, episode_id)
        self._update_normalizers(episode)
        if not self.spec.is_success(episode.ag[-1], episode.g[-1]):
            self.failures += 1
            self.recent_failed_goals.append(np.array(episode.g[-1], np.float32))
        self.inserts += 1
        self.env_steps += self.spec.episode_steps
        return InsertResult(episode_id, False, energy, cluster)

    def _remember(self, key: tuple[str, int], episode_id: int) -> None:
        self._seen[key] = episode_id
        # Forget pairs whose episode left the ring: the oldest entries go first.
        while len(self._seen) > self.store.capacity_episodes:
            self._seen.popitem(last=False)

    def _update_normalizers(self, episode: EpisodeData) -> None:
        obs, g = normalizer_sample(episode, future_p=self.config.her.future_p, rng=self.rng)
        clip = self.config.ddpg.clip_obs
        self.o_norm.update(np.clip(obs, -clip, clip))
        self.g_norm.update(np.clip(g, -clip, clip))
        self.o_norm.recompute_stats()
        self.g_norm.recompute_stats()

    def count_reject(self, reason: str) -> None:
        self.rejects[reason] += 1

    # -- cluster model ---------------------------------------------------------------------
    def set_cluster_model(self, model: ClusterModel) -> bool:
        """Adopt a newer model and relabel every stored episode; False if not newer."""
        if self.cluster_model is not None and model.version <= self.cluster_model.version:
            return False
        if model.k != self.config.cluster.k:
            raise ValueError(f"ClusterModel has k={model.k}, this replay is configured for "
                             f"cluster.k={self.config.cluster.k}; model ignored")
        self.cluster_model = model
        if self.store.size:
            self.store.set_clusters(model.assign(self.store.final_ag))
        return True

    def cluster_sizes(self) -> np.ndarray:
        labels = self.store.cluster
        return np.bincount(labels[labels >= 0], minlength=self.config.cluster.k)

    # -- samples ---------------------------------------------------------------------------
    def sample(self, num_minibatches: int, batch_size: int) -> ServedBatch:
        """`num_minibatches` HER-relabelled minibatches of `batch_size` transitions, with the
        normaliser statistics to train them with (the caller adds the counters)."""
        draws = np.zeros(self.config.cluster.k, np.int64)
        out = []
        moved, sampled = 0, 0
        for _ in range(num_minibatches):
            slots, info = self.sampler.sample(self.store, batch_size, self.rng)
            draws += info.cluster_counts
            moved += int(self.store.moved[slots].sum())
            sampled += len(slots)
            out.append(relabel(self.store, slots, future_p=self.config.her.future_p,
                               reward_fn=self.spec.compute_reward, rng=self.rng))
        self.samples += num_minibatches
        self.cluster_draws_total += draws
        o_stats, g_stats = self.normalizer_state()
        return ServedBatch(minibatches=out, o_stats=o_stats, g_stats=g_stats,
                           cluster_draws=draws, sampled_moved=moved, sampled_transitions=sampled)

    @property
    def buffer_moved_share(self) -> float:
        """Share of the stored episodes whose achieved goal moved (`EpisodeStore.moved`)."""
        return self.store.moved_count / max(self.store.size, 1)

    def normalizer_state(self) -> tuple[NormalizerState, NormalizerState]:
        return self.o_norm.state_dict(), self.g_norm.state_dict()
