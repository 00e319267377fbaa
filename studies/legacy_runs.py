"""The committed runs' history that grouping by settings cannot see: asynchronous runs made
before the lag sources were settings (2026-11-25) predate `learner.prefetch_depth` in their
config.yaml, so hercs' plots would average them with the runs of today's default. Every figure
and table the studies commit keeps them apart as their own variant (`LEGACY_STYLE`, passed to
hercs.apps.plot_tables), which is why this lives here and not in the product's `hercs plot`.
"""

from __future__ import annotations

from typing import Any

from hercs.apps.plot_tables import FigureStyle
from studies.authors_peer import PEER_SCHEDULE

LEGACY_LAG = "lag7"
"""The variant of asynchronous runs made with the old, staler default: rate tolerance 80, two
batches prefetched plus one held, two episodes queued per actor (its policy lag:
docs/results/lag_sources_beside.md)."""


def legacy_lag(config: dict[str, Any]) -> str:
    """`LEGACY_LAG` for an asynchronous run whose resolved config.yaml (one with a `replay`
    section, as every run saves) predates `learner.prefetch_depth`, else ""."""
    schedule = (config.get("training") or {}).get("schedule", "async")
    resolved = "rate_tolerance_updates" in (config.get("replay") or {})
    new = "prefetch_depth" in (config.get("learner") or {})
    return LEGACY_LAG if schedule == "async" and resolved and not new else ""


LEGACY_NOTES = {LEGACY_LAG: "lag 7", PEER_SCHEDULE: ""}
"""How the legacy variant is labelled: a note after the method, "HER-CS (lag 7)"; the
authors' code run here (studies.authors_peer) has no note: its rows say whose it is."""
LEGACY_STYLE = FigureStyle(
    variant_of=legacy_lag, variant_notes=LEGACY_NOTES,
    caption_notes=("(lag 7): asynchronous runs of the old, staler default "
                   "(docs/PERFORMANCE.md §2)",
                   "(authors' code): the authors' published code run on our v1 stack "
                   "(studies/authors_peer)"),
    drawn_by="python -m studies.fig2", not_ours={PEER_SCHEDULE: "authors' code"})
"""The committed figures' styling: hercs' plain one plus the legacy variant."""
