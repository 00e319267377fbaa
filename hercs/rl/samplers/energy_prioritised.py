"""HER-EBP's episode draw: p(slot) ∝ trajectory energy + ε, with replacement.

ε (config.energy.epsilon) keeps every episode drawable and makes an all-zero buffer uniform;
the reference's (ruizhaogit/EnergyBasedPrioritization, her.py) exponent 1/(temperature + 0.01),
0.990 at its default temperature 1, is 1 here, and its lack of ε divides an all-zero buffer
by zero (docs/DESIGN.md §4, §9.3).
"""

from __future__ import annotations

from typing import ClassVar, Self

import numpy as np

from hercs.rl.samplers.base import (
    Needs,
    SampleInfo,
    SamplerSettings,
    SampleSource,
    check_epsilon,
    check_request,
    make_info,
)
from hercs.rl.samplers.sampling_index import WHOLE_BUFFER


class EnergyPrioritisedSampler:
    """p(slot) = (e_slot + ε) / Σ (e + ε). Stateless."""

    needs: ClassVar[Needs] = Needs(energy=True)

    def __init__(self, *, epsilon: float, num_clusters: int = 0, exponent: float = 1.0) -> None:
        check_epsilon(epsilon)
        self.epsilon = epsilon
        self.exponent = exponent
        self.num_clusters = num_clusters

    @classmethod
    def from_settings(cls, settings: SamplerSettings) -> Self:
        return cls(epsilon=settings.epsilon, num_clusters=settings.k, exponent=settings.exponent)

    def sample(
        self, store: SampleSource, batch_size: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, SampleInfo]:
        check_request(store, batch_size)
        idxs = store.sampling_index.draw(np.full(batch_size, WHOLE_BUFFER), rng,
                                         epsilon=self.epsilon, exponent=self.exponent)
        return idxs, make_info(store.cluster, idxs, num_clusters=self.num_clusters)
