"""A sampler that hercs does not ship, written as a new strategy would be (one module): each
episode of a batch comes from one of the labelled clusters, chosen uniformly, then from that
cluster's members uniformly, so a cluster of 3 episodes is drawn as often as one of 2,000.
Before any episode has a label the draw is HER's uniform one. Used by test_new_method.py."""

from __future__ import annotations

from typing import ClassVar, Self

import numpy as np

from hercs.rl.samplers import Needs, SampleInfo, SamplerSettings, SampleSource
from hercs.rl.samplers.base import check_request, make_info


class ClusterUniformSampler:
    """p(slot of cluster c) = 1 / (labelled clusters · n_c). Stateless."""

    needs: ClassVar[Needs] = Needs(clusters=True)

    def __init__(self, *, k: int) -> None:
        self.k = k

    @classmethod
    def from_settings(cls, settings: SamplerSettings) -> Self:
        return cls(k=settings.k)

    def sample(self, store: SampleSource, batch_size: int, rng: np.random.Generator
               ) -> tuple[np.ndarray, SampleInfo]:
        check_request(store, batch_size)
        index = store.sampling_index
        labelled = np.flatnonzero(index.counts[: self.k])
        if labelled.size == 0:
            idxs = rng.integers(0, store.size, batch_size)
        else:  # row c + 1 of the index is cluster c's members
            idxs = index.draw(labelled[rng.integers(0, labelled.size, batch_size)] + 1, rng)
        return idxs, make_info(store.cluster, idxs, num_clusters=self.k)
