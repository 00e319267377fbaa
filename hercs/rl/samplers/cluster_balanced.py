"""HER-CS's episode draw: every cluster of final achieved goals gets an equal share of the batch.

The authors' `clustering_her_random` (ngng9957/Clustering-based-Failed-Goal-Aware-Hindsight-
Experience-Replay, her_modules/her.py; docs/DESIGN.md §4.3): ⌊B/k⌋ per cluster drawn among its
members (a small cluster's each about `repeat` times); what a share cannot use, plus the
remainder, drawn from the whole buffer. Before any cluster model the draw is HER's uniform one;
episodes still unlabelled once a model exists are reachable only through the fills. The output
lists the shares, then the fills: order within a minibatch does not matter, since each entry's
timestep is drawn independently. O(k + B) per call, from the store's `SamplingIndex`.
Departures: docs/DESIGN.md §9.4 (`cluster.share_rule=reference` draws as the authors do).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Self

import numpy as np

from hercs.errors import ConfigError, SamplingError
from hercs.rl.samplers.base import (
    Needs,
    SampleInfo,
    SamplerSettings,
    SampleSource,
    check_request,
    make_info,
)
from hercs.rl.samplers.sampling_index import SamplingIndex
from hercs.rl.samplers.share_rules import SHARE_RULES


@dataclass(frozen=True)
class SharePlan:
    """How many draws each cluster's members get."""

    sizes: np.ndarray
    """(k,) int64 members n_c."""
    member_draws: np.ndarray
    """(k,) int64 draws from c's own members: share, repeat·n_c or 0."""
    fill: int
    """Draws from the whole buffer: B − Σ member_draws."""


def plan_shares(
    index: SamplingIndex, *, k: int, repeat: int, batch_size: int,
    share_rule: str = "every-cluster",
) -> SharePlan | None:
    """The share plan for one batch, or None if no episode has a cluster label yet."""
    if index.max_label >= k:
        raise SamplingError(
            f"cluster label {index.max_label} >= k={k}: the store's labels come from a "
            "model with more clusters than the sampler's; no batch drawn"
        )
    sizes = np.zeros(k, np.int64)
    counts = index.counts
    sizes[: min(k, counts.size)] = counts[:k]
    if sizes.sum() == 0:
        return None
    sharing = SHARE_RULES[share_rule](int(index.max_label), k)
    if sharing <= index.max_label:
        raise SamplingError(
            f"share rule {share_rule!r} splits the batch among {sharing} clusters but the "
            f"store holds cluster label {index.max_label}: its shares would not fit the "
            "batch; no batch drawn")
    share = batch_size // sharing
    small = sizes < share // repeat
    member_draws = np.where(small, repeat * sizes, share)
    member_draws[sizes == 0] = 0
    return SharePlan(
        sizes=sizes,
        member_draws=member_draws.astype(np.int64),
        fill=int(batch_size - member_draws.sum()),
    )


def check_cluster_args(k: int, small_cluster_repeat: int,
                       share_rule: str = "every-cluster") -> None:
    if share_rule not in SHARE_RULES:
        raise ConfigError(f"cluster.share_rule: got {share_rule!r}, must be one of "
                          f"{list(SHARE_RULES)}")
    if k < 1:
        raise ConfigError(f"cluster.k: got {k!r}, must be >= 1")
    if small_cluster_repeat < 1:
        raise ConfigError(
            f"cluster.small_cluster_repeat: got {small_cluster_repeat!r}, must be >= 1"
        )


class ClusterBalancedSampler:
    """HER-CS: equal per-cluster shares with the reference's small/empty-cluster rule.

    Stateless: the plan is made from the store's current cluster sizes on every call.
    """

    needs: ClassVar[Needs] = Needs(clusters=True)

    def __init__(self, k: int, *, small_cluster_repeat: int = 4,
                 share_rule: str = "every-cluster") -> None:
        check_cluster_args(k, small_cluster_repeat, share_rule)
        self.k = k
        self.small_cluster_repeat = small_cluster_repeat
        self.share_rule = share_rule

    @classmethod
    def from_settings(cls, settings: SamplerSettings) -> Self:
        return cls(settings.k, small_cluster_repeat=settings.small_cluster_repeat,
                   share_rule=settings.share_rule)

    def sample(
        self, store: SampleSource, batch_size: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, SampleInfo]:
        check_request(store, batch_size)
        plan = plan_shares(store.sampling_index, k=self.k, repeat=self.small_cluster_repeat,
                           batch_size=batch_size, share_rule=self.share_rule)
        if plan is None:
            idxs = rng.integers(0, store.size, batch_size)
        else:
            idxs = store.sampling_index.draw(share_rows(plan), rng)
        return idxs, make_info(store.cluster, idxs, num_clusters=self.k)


def share_rows(plan: SharePlan) -> np.ndarray:
    """The `SamplingIndex` row of each draw of a plan: cluster c's member draws (row c + 1)
    first, then the whole-buffer fills (row 0)."""
    k = plan.sizes.size
    return np.concatenate([np.repeat(np.arange(1, k + 1), plan.member_draws),
                           np.zeros(plan.fill, np.int64)])
