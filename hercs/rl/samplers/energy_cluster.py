"""HER-EBP-CS's episode draw: cluster-balanced shares, energy-prioritised inside them.

Our definition (docs/DESIGN.md §4.3), with w = trajectory energy + ε: each cluster's draws are
HER-CS's plan; inside cluster c member i is drawn with p = w_i / Σ_{j∈c} w_j; whole-buffer fills
with p ∝ w; before any cluster model it is plain HER-EBP. So a small cluster's repeated draws
favour its energetic members, and episode i of cluster c is drawn member_draws_c · w_i / W_c +
fill · w_i / W times per batch in expectation (W_c, W: the cluster's and the buffer's mass).
Stateless; O(k + B log N) per batch.
"""

from __future__ import annotations

from typing import ClassVar, Self

import numpy as np

from hercs.errors import ConfigError
from hercs.rl.samplers.base import (
    Needs,
    SampleInfo,
    SamplerSettings,
    SampleSource,
    check_epsilon,
    check_request,
    make_info,
)
from hercs.rl.samplers.cluster_balanced import (
    check_cluster_args,
    plan_shares,
    share_rows,
)
from hercs.rl.samplers.sampling_index import WHOLE_BUFFER


class EnergyClusterSampler:
    """HER-EBP-CS as defined in the module docstring."""

    needs: ClassVar[Needs] = Needs(clusters=True, energy=True)

    def __init__(self, k: int, *, epsilon: float, small_cluster_repeat: int = 4,
                 exponent: float = 1.0, cluster_fill: str = "energy",
                 share_rule: str = "every-cluster") -> None:
        check_cluster_args(k, small_cluster_repeat, share_rule)
        check_epsilon(epsilon)
        if cluster_fill not in ("energy", "uniform"):
            raise ConfigError(f"energy.cluster_fill: got {cluster_fill!r}, must be energy or "
                              "uniform")
        self.k = k
        self.epsilon = epsilon
        self.exponent = exponent
        self.cluster_fill = cluster_fill
        self.small_cluster_repeat = small_cluster_repeat
        self.share_rule = share_rule

    @classmethod
    def from_settings(cls, settings: SamplerSettings) -> Self:
        return cls(settings.k, epsilon=settings.epsilon, exponent=settings.exponent,
                   cluster_fill=settings.cluster_fill,
                   small_cluster_repeat=settings.small_cluster_repeat,
                   share_rule=settings.share_rule)

    def sample(
        self, store: SampleSource, batch_size: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, SampleInfo]:
        check_request(store, batch_size)
        index = store.sampling_index
        plan = plan_shares(index, k=self.k, repeat=self.small_cluster_repeat,
                           batch_size=batch_size, share_rule=self.share_rule)
        rows = np.full(batch_size, WHOLE_BUFFER) if plan is None else share_rows(plan)
        if plan is not None and self.cluster_fill == "uniform":  # members uniform, fills by energy
            members = rows != WHOLE_BUFFER
            idxs = np.empty(rows.size, np.int64)
            idxs[members] = index.draw(rows[members], rng)
            idxs[~members] = index.draw(rows[~members], rng, epsilon=self.epsilon,
                                        exponent=self.exponent)
        else:
            idxs = index.draw(rows, rng, epsilon=self.epsilon, exponent=self.exponent)
        return idxs, make_info(store.cluster, idxs, num_clusters=self.k)
