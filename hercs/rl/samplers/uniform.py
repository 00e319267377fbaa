"""HER's episode draw: uniform over stored episodes, with replacement (np.random.randint)."""

from __future__ import annotations

from typing import ClassVar, Self

import numpy as np

from hercs.rl.samplers.base import (
    Needs,
    SampleInfo,
    SamplerSettings,
    SampleSource,
    check_request,
    make_info,
)


class UniformSampler:
    """p(slot) = 1/size. Stateless. `num_clusters` only sizes `SampleInfo.cluster_counts`."""

    needs: ClassVar[Needs] = Needs()

    def __init__(self, *, num_clusters: int = 0) -> None:
        self.num_clusters = num_clusters

    @classmethod
    def from_settings(cls, settings: SamplerSettings) -> Self:
        return cls(num_clusters=settings.k)

    def sample(
        self, store: SampleSource, batch_size: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, SampleInfo]:
        check_request(store, batch_size)
        idxs = rng.integers(0, store.size, batch_size)
        return idxs, make_info(store.cluster, idxs, num_clusters=self.num_clusters)
