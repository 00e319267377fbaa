"""HER-CS's episode draw: every cluster of final achieved goals gets an equal share of the batch.

The rule, as in the authors' code (ngng9957/Clustering-based-Failed-Goal-Aware-Hindsight-
Experience-Replay, her_modules/her.py, `clustering_her_random`), with B episodes, k clusters,
repeat = 4 and n_c members in cluster c:

    share     = ⌊B / k⌋
    n_c ≥ ⌊share / repeat⌋      → share draws from c's members (uniform, with replacement)
    0 < n_c < ⌊share / repeat⌋  → repeat·n_c draws from c's members (so each member ~repeat
                                  times) + share − repeat·n_c uniform draws from the whole buffer
    n_c = 0                     → share uniform draws from the whole buffer
    remainder B − k·share       → uniform draws from the whole buffer

`repeat·n_c < share` for a small cluster, so a fill is never negative. Before any cluster
model (every label −1) the draw is HER's uniform one, as the reference does until its failed-
goal buffer first fills. Episodes still unlabelled once a model exists belong to no cluster and
are reachable only through the whole-buffer fills.

Deviations from the reference, none of which changes a B=256, k=8 batch's distribution:
- The reference iterates over ``max(label) + 1`` clusters (labels predicted on the stored
  episodes), so a top-numbered cluster that no stored episode falls in loses its share to the
  rest; here all k clusters always get a share (an empty one's goes to the whole buffer).
- With B < 4k the reference crashes on an empty cluster (``randint(0, 0)``); here an empty
  cluster always takes the empty-cluster branch, and B < k makes the whole batch a fill.
- The output lists cluster shares first, then the fills (the reference interleaves fills);
  order within a minibatch does not matter, the timestep draw is independent per entry.

Cost per call: O(k + B) — the cluster sizes and member lists come from the store's
`SamplingIndex`, kept up to date on insert, eviction and relabel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hercs.errors import ConfigError, SamplingError
from hercs.replay_service.samplers.base import SampleInfo, SampleSource, check_request, make_info
from hercs.replay_service.sampling_index import SamplingIndex


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
    index: SamplingIndex, *, k: int, repeat: int, batch_size: int
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
    share = batch_size // k
    small = sizes < share // repeat
    member_draws = np.where(small, repeat * sizes, share)
    member_draws[sizes == 0] = 0
    return SharePlan(
        sizes=sizes,
        member_draws=member_draws.astype(np.int64),
        fill=int(batch_size - member_draws.sum()),
    )


def check_cluster_args(k: int, small_cluster_repeat: int) -> None:
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

    def __init__(self, k: int, *, small_cluster_repeat: int = 4) -> None:
        check_cluster_args(k, small_cluster_repeat)
        self.k = k
        self.small_cluster_repeat = small_cluster_repeat

    def sample(
        self, store: SampleSource, batch_size: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, SampleInfo]:
        check_request(store, batch_size)
        plan = plan_shares(store.sampling_index, k=self.k, repeat=self.small_cluster_repeat,
                           batch_size=batch_size)
        if plan is None:
            idxs = rng.integers(0, store.size, batch_size)
            fill, balanced = batch_size, False
        else:
            idxs = store.sampling_index.draw(share_rows(plan), rng)
            fill, balanced = plan.fill, True
        return idxs, make_info(
            store.cluster, idxs, num_clusters=self.k, whole_buffer_draws=fill,
            balanced=balanced
        )


def share_rows(plan: SharePlan) -> np.ndarray:
    """The `SamplingIndex` row of each draw of a plan: cluster c's member draws (row c + 1)
    first, then the whole-buffer fills (row 0)."""
    k = plan.sizes.size
    return np.concatenate([np.repeat(np.arange(1, k + 1), plan.member_draws),
                           np.zeros(plan.fill, np.int64)])
