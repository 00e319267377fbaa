"""A preallocated buffer of whole episodes with per-episode metadata: a FIFO ring, or the
reference's random overwrite once full (`replay.eviction`, docs/DESIGN.md §9.2).

Episode ids are global and monotonic; an id's slot is a pure function of it (`slot_for`), so
replaying the log in id order rebuilds the same buffer (ids below capacity go to slot id,
later ones to id % capacity for `fifo` or a slot hashed from (eviction seed, id) for `random`).
Valid slots are `[0, size)`; arrays of the wrong shape are refused before anything is written.
Storage is `np.zeros` (calloc), so a 10^6-transition buffer commits memory only as slots are
written. Not thread-safe.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from hercs.config import EVICTIONS
from hercs.errors import ConfigError
from hercs.rl.samplers.sampling_index import SamplingIndex
from hercs.rl.task_registry import TaskSpec
from hercs.wire.episode import EpisodeData, expected_shapes

UNASSIGNED = -1
"""Cluster label of an episode that no cluster model has labelled yet."""
MOVED_THRESHOLD_M = 0.005
"""An episode's achieved goal *moved* when it got farther than this from where it started (the
object, in the object tasks; the gripper in Reach). 5 mm is far above the simulator's jitter of
a resting object and far below any push that matters: the episodes HER-CS and EBP exist to
draw more often are the ones where it moved."""
_MASK64 = (1 << 64) - 1


def _mix64(value: int) -> int:
    """SplitMix64's finaliser: a 64-bit integer hash whose low bits are uniform."""
    z = (value + 0x9E3779B97F4A7C15) & _MASK64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    return z ^ (z >> 31)

_ARRAY_FIELDS = ("obs", "ag", "g", "actions")
_META_FIELDS = (
    "episode_id", "actor_id", "seq", "success", "final_ag", "energy", "cluster", "policy_version",
    "moved",
)


def _readonly(view: np.ndarray) -> np.ndarray:
    view.flags.writeable = False
    return view


class EpisodeStore:
    """Ring buffer of `capacity_episodes` episodes of one task (see the module invariants)."""

    def __init__(self, *, capacity_episodes: int, spec: TaskSpec, eviction: str = "fifo",
                 eviction_seed: int = 0) -> None:
        if capacity_episodes < 1:
            raise ConfigError(
                f"EpisodeStore capacity_episodes: got {capacity_episodes!r}, must be >= 1"
            )
        if eviction not in EVICTIONS:
            raise ConfigError(f"EpisodeStore eviction: got {eviction!r}, must be one of "
                              f"{', '.join(EVICTIONS)}")
        self._eviction = eviction
        self._eviction_key = _mix64(int(eviction_seed) & _MASK64)
        self._spec = spec
        self._capacity = int(capacity_episodes)
        self._shapes = expected_shapes(spec)
        n = self._capacity
        self._obs = np.zeros((n, *self._shapes["obs"]), np.float32)
        self._ag = np.zeros((n, *self._shapes["ag"]), np.float32)
        self._g = np.zeros((n, *self._shapes["g"]), np.float32)
        self._actions = np.zeros((n, *self._shapes["actions"]), np.float32)
        self._episode_id = np.zeros(n, np.int64)
        self._actor_id = np.empty(n, object)
        self._seq = np.zeros(n, np.int64)
        self._success = np.zeros(n, bool)
        self._final_ag = np.zeros((n, spec.goal_dim), np.float32)
        self._energy = np.zeros(n, np.float64)
        self._cluster = np.full(n, UNASSIGNED, np.int32)
        self._policy_version = np.zeros(n, np.int64)
        self._moved = np.zeros(n, bool)
        self.moved_count = 0
        """Stored episodes whose achieved goal moved (`MOVED_THRESHOLD_M`)."""
        self._size = 0
        self._next_id = 0
        self._index = SamplingIndex(n)

    # ------------------------------------------------------------------ sizes

    @property
    def spec(self) -> TaskSpec:
        return self._spec

    @property
    def capacity_episodes(self) -> int:
        return self._capacity

    @property
    def size(self) -> int:
        """Stored episodes (= number of valid slots)."""
        return self._size

    @property
    def num_transitions(self) -> int:
        """Stored transitions: size × T."""
        return self._size * self._spec.episode_steps

    @property
    def num_inserted(self) -> int:
        """Episodes ever inserted (= the id the next insert gets)."""
        return self._next_id

    @property
    def eviction(self) -> str:
        return self._eviction

    def slot_for(self, episode_id: int) -> int:
        """The slot episode `episode_id` is (or was) written to (module invariants)."""
        if episode_id < self._capacity or self._eviction == "fifo":
            return episode_id % self._capacity
        return _mix64(self._eviction_key ^ episode_id) % self._capacity

    # ------------------------------------------------------------------ writes

    def insert(
        self, episode: EpisodeData, *, energy: float = 0.0, cluster: int = UNASSIGNED
    ) -> int:
        """Store `episode` in slot `slot_for(id)` (overwriting an episode when full).

        `energy` is the trajectory energy (hercs.replay_service.energy), `cluster` the episode's
        label under the current cluster model (-1 if there is none). Returns the episode id.
        Raises ConfigError, storing nothing, if a shape or a metadata value is wrong.
        """
        arrays = self._checked_arrays(episode, energy, cluster)
        episode_id = self._next_id
        slot = self.slot_for(episode_id)
        if episode_id >= self._capacity:  # the slot's episode leaves
            self.moved_count -= int(self._moved[slot])
        self._write(slot, episode_id, episode, arrays, energy=energy, cluster=cluster)
        self.moved_count += int(self._moved[slot])
        self._index.put(slot, energy=float(energy), label=int(cluster))
        self._next_id += 1
        self._size = min(self._size + 1, self._capacity)
        return episode_id

    def _checked_arrays(self, episode: EpisodeData, energy: float, cluster: int
                        ) -> dict[str, np.ndarray]:
        arrays = {name: np.asarray(getattr(episode, name)) for name in _ARRAY_FIELDS}
        for name, arr in arrays.items():
            if arr.shape != self._shapes[name]:
                raise ConfigError(
                    f"EpisodeStore.insert: episode.{name} has shape {arr.shape}, expected "
                    f"{self._shapes[name]} for task {self._spec.name!r}; the episode is not "
                    "stored (the sender's task does not match the replay's)"
                )
        if not np.isfinite(energy) or energy < 0:
            raise ConfigError(
                f"EpisodeStore.insert: energy got {energy!r}, must be finite and >= 0; "
                "the episode is not stored"
            )
        if cluster < UNASSIGNED:
            raise ConfigError(
                f"EpisodeStore.insert: cluster got {cluster!r}, must be >= -1 (-1 = unassigned); "
                "the episode is not stored"
            )
        return arrays

    def _write(self, slot: int, episode_id: int, episode: EpisodeData,
               arrays: dict[str, np.ndarray], *, energy: float, cluster: int) -> None:
        """Write one checked episode into `slot` (the sampling index is the caller's)."""
        ag = arrays["ag"]
        self._moved[slot] = bool(np.linalg.norm(ag - ag[:1], axis=-1).max() > MOVED_THRESHOLD_M)
        self._obs[slot] = arrays["obs"]
        self._ag[slot] = arrays["ag"]
        self._g[slot] = arrays["g"]
        self._actions[slot] = arrays["actions"]
        self._episode_id[slot] = episode_id
        self._actor_id[slot] = str(episode.actor_id)
        self._seq[slot] = int(episode.seq)
        self._success[slot] = bool(episode.success)
        self._final_ag[slot] = arrays["ag"][-1]
        self._energy[slot] = float(energy)
        self._cluster[slot] = int(cluster)
        self._policy_version[slot] = int(episode.policy_version)

    def restore(self, episodes: Iterable[tuple[int, EpisodeData, float]], *,
                next_id: int) -> None:
        """Refill an empty store as it was once `next_id` episodes had been inserted: a
        restarted replay whose log starts from a saved state (`ReplayTable.recover`).

        `episodes`: (id, episode, energy) in increasing id order, every id from the oldest one
        the store held then up to `next_id` − 1 (the log's; a later id overwrites an earlier
        one of the same slot, as `insert` would have). Labels are unassigned (a cluster model
        relabels them). Raises ConfigError, leaving the store empty, if an episode is out of
        range or a slot stays unfilled (the log lacks episodes the store held)."""
        if self._next_id:
            raise ConfigError(f"EpisodeStore.restore: the store holds {self._size} episodes "
                              "already; only an empty store is restored")
        size = min(int(next_id), self._capacity)
        filled = np.zeros(self._capacity, bool)
        last = -1
        for episode_id, episode, energy in episodes:
            if not last < episode_id < next_id:
                raise ConfigError(f"EpisodeStore.restore: episode id {episode_id} after "
                                  f"{last}: ids must increase and stay below {next_id}")
            arrays = self._checked_arrays(episode, energy, UNASSIGNED)
            slot = self.slot_for(episode_id)
            self._write(slot, episode_id, episode, arrays, energy=energy, cluster=UNASSIGNED)
            filled[slot], last = True, episode_id
        if not filled[:size].all():
            self._moved[:] = False
            raise ConfigError(
                f"EpisodeStore.restore: {int(size - filled[:size].sum())} of {size} slots got no "
                f"episode (ids up to {last} given): the log lacks episodes the buffer held")
        self._next_id, self._size = int(next_id), size
        self.moved_count = int(self._moved[:size].sum())
        self._index.rebuild(self._energy[:size].copy(), self._cluster[:size].astype(np.int64))

    def set_clusters(self, labels: np.ndarray) -> None:
        """Relabel every stored episode (a new cluster model): `labels` has shape (size,)."""
        labels = np.asarray(labels)
        if labels.shape != (self._size,):
            raise ConfigError(
                f"EpisodeStore.set_clusters: labels have shape {labels.shape}, expected "
                f"({self._size},) (one per stored episode); labels unchanged"
            )
        if labels.size and int(labels.min()) < UNASSIGNED:
            raise ConfigError(
                f"EpisodeStore.set_clusters: got label {int(labels.min())}, labels must be "
                ">= -1; labels unchanged"
            )
        self._cluster[: self._size] = labels
        self._index.relabel(labels)

    # ------------------------------------------------------------------ views of valid slots

    def _view(self, arr: np.ndarray) -> np.ndarray:
        return _readonly(arr[: self._size])

    @property
    def obs(self) -> np.ndarray:
        """(size, T+1, obs_dim) float32."""
        return self._view(self._obs)

    @property
    def ag(self) -> np.ndarray:
        """(size, T+1, goal_dim) float32: achieved goals ag_0..ag_T."""
        return self._view(self._ag)

    @property
    def g(self) -> np.ndarray:
        """(size, T, goal_dim) float32: desired goals."""
        return self._view(self._g)

    @property
    def actions(self) -> np.ndarray:
        """(size, T, action_dim) float32."""
        return self._view(self._actions)

    @property
    def episode_id(self) -> np.ndarray:
        return self._view(self._episode_id)

    @property
    def actor_id(self) -> np.ndarray:
        return self._view(self._actor_id)

    @property
    def seq(self) -> np.ndarray:
        return self._view(self._seq)

    @property
    def success(self) -> np.ndarray:
        return self._view(self._success)

    @property
    def final_ag(self) -> np.ndarray:
        """(size, goal_dim) float32: ag_T, the point clustered by HER-CS."""
        return self._view(self._final_ag)

    @property
    def energy(self) -> np.ndarray:
        """(size,) float64 trajectory energies."""
        return self._view(self._energy)

    @property
    def cluster(self) -> np.ndarray:
        """(size,) int32 cluster labels, -1 = unassigned."""
        return self._view(self._cluster)

    @property
    def sampling_index(self) -> SamplingIndex:
        """Cluster members and energy sum trees over the stored slots, kept in step with
        every insert, eviction and relabel (the samplers draw from it in O(batch))."""
        return self._index

    @property
    def policy_version(self) -> np.ndarray:
        return self._view(self._policy_version)

    @property
    def moved(self) -> np.ndarray:
        """(size,) bool: the episode's achieved goal moved (`MOVED_THRESHOLD_M`)."""
        return self._view(self._moved)

    def slot_of(self, episode_id: int) -> int | None:
        """The slot holding `episode_id`, or None if it was never inserted or was overwritten."""
        if not 0 <= episode_id < self._next_id:
            return None
        slot = self.slot_for(episode_id)
        return slot if int(self._episode_id[slot]) == episode_id else None

    def episode(self, episode_id: int) -> EpisodeData | None:
        """A copy of the stored episode `episode_id` as it was inserted, or None if it was
        never inserted or has been overwritten (a copy: the slot may be reused later)."""
        slot = self.slot_of(episode_id)
        if slot is None:
            return None
        return EpisodeData(
            obs=self._obs[slot].copy(), ag=self._ag[slot].copy(), g=self._g[slot].copy(),
            actions=self._actions[slot].copy(), actor_id=str(self._actor_id[slot]),
            seq=int(self._seq[slot]), success=bool(self._success[slot]),
            policy_version=int(self._policy_version[slot]),
        )
