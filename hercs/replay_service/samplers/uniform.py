"""HER's episode draw: uniform over stored episodes, with replacement (np.random.randint)."""

from __future__ import annotations

import numpy as np

from hercs.replay_service.samplers.base import SampleInfo, SampleSource, check_request, make_info


class UniformSampler:
    """p(slot) = 1/size. Stateless. `num_clusters` only sizes `SampleInfo.cluster_counts`."""

    def __init__(self, *, num_clusters: int = 0) -> None:
        self.num_clusters = num_clusters

    def sample(
        self, store: SampleSource, batch_size: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, SampleInfo]:
        check_request(store, batch_size)
        idxs = rng.integers(0, store.size, batch_size)
        return idxs, make_info(
            store.cluster, idxs, num_clusters=self.num_clusters,
            whole_buffer_draws=batch_size, balanced=False,
        )
