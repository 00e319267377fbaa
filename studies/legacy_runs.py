"""The committed runs' history in the studies' own words: asynchronous runs made before the
lag sources were settings (2026-11-25) ran with the old, staler default, which hercs' plots
key by its settings (`lag=80,3,2,-1`, hercs.apps.plots.series.PolicyLag) and the studies'
reports call by the policy lag it gave, "lag 7" (docs/results/lag_sources_beside.md)."""

from __future__ import annotations

from hercs.apps.plots.series import PolicyLag

LEGACY_LAG = PolicyLag(tolerance=80, prefetch=3, queue=2, bound=-1).component()
"""The key part of asynchronous runs made with the old default: rate tolerance 80, two
batches prefetched plus one held, two episodes queued per actor, no bound."""
LEGACY_NOTES = {LEGACY_LAG: "lag 7"}
"""How the studies' reports label it: a note after the method, "HER-CS (lag 7)"."""
