"""The replay service's core: everything the replay does, with no transport.

`ReplayCore` owns the episode store, the sampler, the o/g normalisers, the cluster model and
the status counters. Invariants: an (actor_id, seq) pair is stored at most once; every stored
episode carries its cluster under the current model (-1 before one); normaliser statistics
cover every stored episode.
"""

from __future__ import annotations

import itertools
from collections import Counter, OrderedDict, deque
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from hercs.config import HercsConfig
from hercs.errors import ConfigError
from hercs.reasons import Reason
from hercs.replay_service.energy import trajectory_energy
from hercs.replay_service.her import normalizer_sample, relabel
from hercs.replay_service.store import EpisodeStore
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.methods import make_sampler
from hercs.rl.normalizer import Normalizer, NormalizerState
from hercs.rl.plausibility import implausible, winsorised
from hercs.rl.seeding import int_seed
from hercs.run.runlog.format import EpisodeLogError
from hercs.wire.episode import EpisodeData
from hercs.wire.replay_state import ReplayState
from hercs.wire.served import ServedBatch


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
        self.sampler = make_sampler(config.run.method, config.sampler_settings)
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
        self.newest_policy_version: int | None = None
        """The newest weights version any stored episode was acted with (None before the
        first): after a restart, a floor under the learner's newest weights (they existed)."""
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
        energy = self._energy(episode)
        cluster = -1
        if self.cluster_model is not None:
            cluster = int(self.cluster_model.assign(episode.ag[-1:])[0])
        episode_id = self.store.insert(episode, energy=energy, cluster=cluster)
        self._remember(key, episode_id)
        self._saw_version(episode.policy_version)
        self._update_normalizers(episode)
        if not self.spec.is_success(episode.ag[-1], episode.g[-1]):
            self.failures += 1
            self.recent_failed_goals.append(np.array(episode.g[-1], np.float32))
        self.inserts += 1
        self.env_steps += self.spec.episode_steps
        return InsertResult(episode_id, False, energy, cluster)

    def _energy(self, episode: EpisodeData) -> float:
        """The episode's trajectory energy by its task's energy kind (0 where it has none),
        the same at insert and at a restore."""
        if self.spec.energy == "none":
            return 0.0
        return float(trajectory_energy(episode.ag, self.config.energy, self.spec.energy))

    def _saw_version(self, policy_version: int) -> None:
        newest = self.newest_policy_version
        self.newest_policy_version = (int(policy_version) if newest is None
                                      else max(newest, int(policy_version)))

    # -- a saved state (the bounded episode log) -----------------------------------------------
    def state(self, stored_per_version: Mapping[int, int]) -> ReplayState:
        """What this core derived from every episode inserted so far, beyond the episodes its
        store holds (`hercs.wire.replay_state`); `stored_per_version` is the lockstep gate's."""
        held = self.store.episode_id
        return ReplayState(
            next_episode_id=self.store.num_inserted,
            first_held_id=int(held.min()) if held.size else 0, failures=self.failures,
            recent_failed_goals=self.failed_goals(), o_stats=self.o_norm.state_dict(),
            g_stats=self.g_norm.state_dict(), cluster_model=self.cluster_model,
            stored_per_version=dict(stored_per_version))

    def recover(self, episodes: Iterable[tuple[int, EpisodeData]],
                state: ReplayState | None = None) -> tuple[list[tuple[int, int]], Counter[int]]:
        """Insert a restarted replay's logged (id, episode) pairs, or with the log's newest
        `state`, restore that state (`restore`: the episodes before its first_held_id are
        skipped, those up to its next_episode_id restored) and insert only the later ones.
        Returns the (logged id, stored id) pairs that disagree and the episodes per policy
        version (the lockstep gate's)."""
        versions: Counter[int] = Counter()
        if state is not None:
            held, episodes = split_at_state(episodes, state)
            self.restore(state, held)
            versions.update(state.stored_per_version)
        else:
            source = iter(episodes)
            first = next(source, None)
            if first is not None and first[0] != 0:
                raise EpisodeLogError(
                    f"the episode log starts at episode {first[0]} and holds no replay state "
                    "to start from: its first segments were removed by hand; put them back")
            episodes = itertools.chain([first] if first is not None else [], source)
        mismatched = []
        for episode_id, episode in episodes:
            stored = self.insert(episode)
            if stored.episode_id != episode_id:
                mismatched.append((episode_id, stored.episode_id))
            versions[episode.policy_version] += 1
        return mismatched, versions

    def restore(self, state: ReplayState, held: Iterable[tuple[int, EpisodeData]]) -> None:
        """Start a fresh core from `state` and the logged episodes from its `first_held_id` up
        to its `next_episode_id` − 1, in order: the same store, dedup keys, counts, failed
        goals and normalisers as the core that saved `state` (its cluster model is the
        caller's to adopt, as after a replay of the whole log). Raises ConfigError if `held`
        lacks an episode the store held."""
        if self.store.num_inserted:
            raise ConfigError("ReplayCore.restore: this core has stored episodes already")
        kept = state.next_episode_id - state.first_held_id
        if kept < min(state.next_episode_id, self.store.capacity_episodes):
            raise EpisodeLogError(
                f"the episode log's newest replay state keeps the {kept} episodes from id "
                f"{state.first_held_id} on, fewer than this replay's buffer of "
                f"{self.store.capacity_episodes} holds: it was written with a smaller "
                "replay.buffer_transitions; resume with the run's own, or start a new run")

        def with_energy() -> Iterator[tuple[int, EpisodeData, float]]:
            for episode_id, episode in held:
                self._remember((episode.actor_id, int(episode.seq)), episode_id)
                self._saw_version(episode.policy_version)
                yield episode_id, episode, self._energy(episode)

        self.store.restore(with_energy(), next_id=state.next_episode_id)
        self.o_norm.load_state_dict(state.o_stats)
        self.g_norm.load_state_dict(state.g_stats)
        self.failures = state.failures
        self.recent_failed_goals.clear()
        self.recent_failed_goals.extend(np.asarray(g, np.float32)
                                        for g in state.recent_failed_goals)
        self.inserts = state.next_episode_id
        self.env_steps = state.next_episode_id * self.spec.episode_steps

    def failed_goals(self) -> np.ndarray:
        """(n ≤ fgb_size, goal_dim) float32: `recent_failed_goals` as one array."""
        if not self.recent_failed_goals:
            return np.zeros((0, self.spec.goal_dim), np.float32)
        return np.stack(list(self.recent_failed_goals))

    def _remember(self, key: tuple[str, int], episode_id: int) -> None:
        self._seen[key] = episode_id
        # Forget pairs whose episode left the ring: the oldest entries go first.
        while len(self._seen) > self.store.capacity_episodes:
            self._seen.popitem(last=False)

    def _update_normalizers(self, episode: EpisodeData) -> None:
        obs, g = normalizer_sample(episode, future_p=self.config.her.future_p, rng=self.rng)
        clip = self.config.ddpg.clip_obs
        self.o_norm.update(winsorised(self.o_norm, np.clip(obs, -clip, clip)))
        self.g_norm.update(winsorised(self.g_norm, np.clip(g, -clip, clip)))
        self.o_norm.recompute_stats()
        self.g_norm.recompute_stats()

    def implausible(self, episode: EpisodeData) -> tuple[Reason, str] | None:
        """Why `episode`'s values lie beyond what the running statistics make plausible
        (hercs.rl.plausibility), or None to admit it."""
        for norm, values, what in ((self.o_norm, episode.obs, "obs"),
                                   (self.g_norm, episode.ag, "achieved_goal"),
                                   (self.g_norm, episode.g, "desired_goal")):
            detail = implausible(norm, values, what=what)
            if detail is not None:
                return Reason.IMPLAUSIBLE, f"episode refused: {detail}"
        return None

    def count_reject(self, reason: Reason) -> None:
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


def split_at_state(episodes: Iterable[tuple[int, EpisodeData]], state: ReplayState
                   ) -> tuple[Iterator[tuple[int, EpisodeData]], Iterator[tuple[int, EpisodeData]]]:
    """A restarted replay's logged episodes, in id order, as (those `state` held: from its
    first_held_id to its next_episode_id − 1; the ones after it). Ids before first_held_id
    (in segments not deleted yet) are skipped. Consume the first before the second."""
    source = iter(episodes)
    after: list[tuple[int, EpisodeData]] = []

    def held() -> Iterator[tuple[int, EpisodeData]]:
        for pair in source:
            if pair[0] >= state.next_episode_id:
                after.append(pair)
                return
            if pair[0] >= state.first_held_id:
                yield pair

    def later() -> Iterator[tuple[int, EpisodeData]]:
        yield from after
        yield from source

    return held(), later()
