"""studies/legacy_runs: the studies' name for the old lag default is hercs' key of a run made
with it, so their reports and `hercs plot` group the same runs."""

from __future__ import annotations

from hercs.apps.plots.curves import method_label
from hercs.apps.plots.series import series_key
from studies.legacy_runs import LEGACY_LAG, LEGACY_NOTES

OLD = {"run": {"method": "her-cs", "seed": 1}, "task": {"name": "push"},
       "replay": {"rate_tolerance_updates": 80.0}}  # saved before learner.prefetch_depth


def test_a_run_of_the_old_default_has_the_legacy_lag_in_its_key() -> None:
    assert series_key(OLD) == f"her-cs/{LEGACY_LAG}"
    assert series_key({**OLD, "training": {"schedule": "lockstep"}}) == "her-cs/lockstep"
    new = {**OLD, "replay": {"rate_tolerance_updates": 40.0},
           "learner": {"prefetch_depth": 0}, "actor": {"insert_queue": 0},
           "training": {"max_policy_lag": 3}}
    assert series_key(new) == "her-cs"


def test_the_studies_label_it_lag_7_where_hercs_plot_names_its_settings() -> None:
    assert method_label(f"her-cs/{LEGACY_LAG}", LEGACY_NOTES) == "HER-CS, lag 7"
    assert method_label(f"her-ebp-cs/lockstep/bf16/{LEGACY_LAG}",
                        LEGACY_NOTES) == (
        "HER-EBP-CS, lockstep (as the authors' code), bf16 learner, lag 7")
    assert method_label(f"her-cs/{LEGACY_LAG}") == (
        "HER-CS, no lag bound, prefetch 3, actor queue 2, rate tolerance 80")
