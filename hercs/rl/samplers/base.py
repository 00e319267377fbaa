"""The episode-sampler protocol, what a sampler needs and is built from, what a draw reports,
and shared vectorised draw primitives.

A sampler chooses which *episodes* (store slots) go into a minibatch and returns slot indices
plus a `SampleInfo`, never data. Samplers hold no state between calls: they read the store's
`SamplingIndex` (O(k + B log N) per draw) and take randomness from the injected generator.
Each declares what its draw reads beyond the slots (`Needs`): the clusterer fits cluster
models only for a sampler that needs them, and the config refuses an energy-reading one on a
task without trajectory energy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Protocol, Self

import numpy as np

from hercs.errors import ConfigError, SamplingError
from hercs.rl.samplers.sampling_index import SamplingIndex


@dataclass(frozen=True)
class Needs:
    """What a sampler's draw reads of the stored episodes besides their number."""

    clusters: bool = False
    """Their cluster labels: the run's clusterer fits k-means models on failed goals, and the
    lockstep gate waits for a model after each refit."""
    energy: bool = False
    """Their trajectory energies: the task must define one (hercs.rl.task_registry)."""


@dataclass(frozen=True)
class SamplerSettings:
    """Every value a sampler may be built from, as the run's config gives them
    (`HercsConfig.sampler_settings`); each sampler takes the ones it uses."""

    k: int
    """cluster.k: the clusters of a model, and the length of `SampleInfo.cluster_counts`."""
    small_cluster_repeat: int
    """cluster.small_cluster_repeat."""
    share_rule: str
    """cluster.share_rule: a row of hercs.rl.samplers.share_rules.SHARE_RULES."""
    epsilon: float
    """energy.epsilon as the run resolved it (`HercsConfig.energy_epsilon`)."""
    exponent: float
    """energy.exponent."""
    cluster_fill: str
    """energy.cluster_fill."""


class SampleSource(Protocol):
    """What samplers read from the store: `EpisodeStore` satisfies it."""

    @property
    def size(self) -> int: ...
    @property
    def cluster(self) -> np.ndarray: ...  # (size,) int32, -1 = unassigned
    @property
    def energy(self) -> np.ndarray: ...  # (size,) float64 trajectory energies
    @property
    def sampling_index(self) -> SamplingIndex: ...


@dataclass(frozen=True)
class SampleInfo:
    """What one draw did, for the per-cluster-share metric and `Batch.cluster_draws`."""

    cluster_counts: np.ndarray
    """(num_clusters,) int64: drawn episodes per stored cluster label, whichever route drew
    them (own-cluster share or whole-buffer fill); unlabelled ones (-1) are not counted."""


class EpisodeSampler(Protocol):
    needs: ClassVar[Needs]
    """What its draw reads of the stored episodes."""

    @classmethod
    def from_settings(cls, settings: SamplerSettings) -> Self:
        """The sampler a run's settings make."""
        ...

    def sample(
        self, store: SampleSource, batch_size: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, SampleInfo]:
        """Draw `batch_size` slots (int64, in [0, store.size), with replacement)."""
        ...


def check_request(store: SampleSource, batch_size: int) -> None:
    """Refuse a draw that cannot be made, naming the value."""
    if batch_size < 1:
        raise SamplingError(f"batch_size got {batch_size!r}, must be >= 1; no batch drawn")
    if store.size < 1:
        raise SamplingError(
            f"cannot draw {batch_size} episodes: the store is empty; the request waits for "
            "inserts"
        )


def check_epsilon(epsilon: float) -> None:
    if not epsilon > 0:
        raise ConfigError(f"energy.epsilon: got {epsilon!r}, must be > 0 (no episode may have p=0)")


def make_info(labels: np.ndarray, idxs: np.ndarray, *, num_clusters: int) -> SampleInfo:
    drawn = labels[idxs]
    return SampleInfo(
        cluster_counts=np.bincount(drawn[drawn >= 0], minlength=num_clusters).astype(np.int64))
