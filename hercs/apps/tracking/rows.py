"""What a tracker is sent, from a run's own files and with no tracker imported: an epoch's
scalars from its metrics.csv row, the resolved config as flat hyperparameters, and the rows of
metrics.csv that are complete."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import yaml

from hercs.run.metrics import parse_table

PANELS = {
    "success_rate": "eval", "mean_final_distance": "eval",
    "critic_loss": "loss", "actor_loss": "loss", "q_mean": "loss",
    "env_steps_per_s": "throughput", "updates_per_s": "throughput",
    "batch_wait_s": "throughput",
    "replay_size": "replay", "policy_lag": "replay", "policy_lag_request": "replay",
    "weights_version": "replay", "bad_batches": "replay",
    "cluster_model_version": "clusters",
}
"""The panel each metrics.csv column is plotted in, so a panel holds one unit; any other
number goes to `progress/`."""
PER_CLUSTER = {"cluster_sizes": "size", "cluster_share": "share"}
"""metrics.csv's per-cluster columns ("12;0;7"): cluster i's episodes in the replay's model
and its share of the epoch's draws, sent as clusters/size_i and clusters/share_i."""
TEXT_COLUMNS = frozenset({"epoch", "rejects"})
"""Not sent as scalars: the epoch is the step; the refusals by reason stay in metrics.csv."""


def epoch_scalars(row: Mapping[str, str]) -> dict[str, float]:
    """One metrics.csv row's numbers under their panel's name (eval/success_rate, …) and the
    cluster model's sizes per cluster (clusters/size_0, …). Blanks and NaN are left out: no
    tracker plots them, and an epoch without a lag sample (after a replay restart) has one."""
    scalars: dict[str, float] = {}
    for name, text in row.items():
        if name in TEXT_COLUMNS or name is None or not text:
            continue
        if name in PER_CLUSTER:
            for i, item in enumerate(text.split(";")):
                _put(scalars, f"clusters/{PER_CLUSTER[name]}_{i}", item)
        else:
            _put(scalars, f"{PANELS.get(name, 'progress')}/{name}", text)
    return scalars


def _put(scalars: dict[str, float], key: str, text: str) -> None:
    try:
        value = float(text)
    except ValueError:  # a column of text another version added: it stays in metrics.csv
        return
    if math.isfinite(value):
        scalars[key] = value


def complete_rows(text: str) -> list[dict[str, str]]:
    """The rows of metrics.csv's text, without a last line still being written (no line end
    yet): it is read again once whole."""
    whole = text[:text.rfind("\n") + 1]
    return [row for row in parse_table(whole)[1] if row.get("epoch")]


def flat_hyperparameters(config: Mapping[str, Any]) -> dict[str, bool | int | float | str]:
    """The config's sections as `section.field` → value, as `--set` spells them: a list as its
    YAML text ([a, b]), None as null; trackers whose parameters are flat (MLflow,
    TensorBoard's HParams) take these."""
    flat: dict[str, bool | int | float | str] = {}
    for section, fields in config.items():
        for name, value in fields.items():
            if isinstance(value, bool | int | float | str):
                flat[f"{section}.{name}"] = value
            else:
                flat[f"{section}.{name}"] = yaml.safe_dump(
                    value, default_flow_style=True).strip().removesuffix("\n...")
    return flat
