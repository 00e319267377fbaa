"""How many clusters share a cluster-balanced batch: one function a rule, one row in
`SHARE_RULES` (`cluster.share_rule` names the row; docs/DESIGN.md §9.4)."""

from __future__ import annotations

from collections.abc import Callable

ShareRule = Callable[[int, int], int]
"""(the highest cluster label of any stored episode, k) → the number of clusters that split
the batch: at least that label + 1, or the shares would not fit the batch."""


def every_cluster(max_label: int, k: int) -> int:
    """hercs' default: every one of the k clusters gets ⌊B/k⌋, empty ones included (their
    share goes to the whole-buffer fill)."""
    return k


def up_to_highest_label(max_label: int, k: int) -> int:
    """The reference's code: the clusters up to the highest label any stored episode has
    (labels 0..m) split the batch, ⌊B/(m+1)⌋ each; with k = 8 and cluster 7 empty, 7 shares
    of 36 instead of 8 of 32."""
    return max_label + 1


SHARE_RULES: dict[str, ShareRule] = {
    "every-cluster": every_cluster,
    "reference": up_to_highest_label,
}
"""`cluster.share_rule` → its rule; the first row is the default."""
