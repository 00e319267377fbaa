"""studies/legacy_runs.py: which configs are the legacy variant, and the styling the committed
figures get from it."""

from __future__ import annotations

from hercs.apps.plots import method_label
from studies.legacy_runs import LEGACY_LAG, LEGACY_STYLE, legacy_lag

RESOLVED = {"replay": {"rate_tolerance_updates": 80}}


def test_only_a_resolved_asynchronous_config_without_prefetch_depth_is_legacy() -> None:
    assert legacy_lag(RESOLVED) == LEGACY_LAG  # async is the default schedule
    assert legacy_lag({**RESOLVED, "training": {"schedule": "async"}}) == LEGACY_LAG
    assert legacy_lag({**RESOLVED, "learner": {"prefetch_depth": 3}}) == ""
    assert legacy_lag({**RESOLVED, "training": {"schedule": "lockstep"}}) == ""
    assert legacy_lag({"task": {"name": "push"}}) == ""  # not a resolved config: no replay


def test_the_committed_figures_label_and_explain_the_legacy_variant() -> None:
    assert LEGACY_STYLE.variant_of is legacy_lag
    assert method_label(f"her-cs/{LEGACY_LAG}", LEGACY_STYLE.variant_notes) == "HER-CS (lag 7)"
    assert method_label(f"her-ebp-cs/lockstep/bf16/{LEGACY_LAG}",
                        LEGACY_STYLE.variant_notes) == "HER-EBP-CS lockstep bf16 (lag 7)"
    assert any(note.startswith("(lag 7): ") for note in LEGACY_STYLE.caption_notes)
    assert LEGACY_STYLE.drawn_by == "python -m studies.fig2"
