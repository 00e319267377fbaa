"""A run's `metrics.csv` (hercs.rundir.METRICS): its columns, the learner's writer, and the
readers that services, apps and benchmarks share. One row per evaluated epoch; a resumed run
keeps its file's columns (older runs may have fewer)."""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

METRICS_COLUMNS = [
    "epoch", "env_steps", "episodes", "updates", "success_rate", "mean_final_distance",
    "wall_s", "env_steps_per_s", "updates_per_s", "replay_size", "policy_lag", "weights_version",
    "cluster_model_version", "cluster_sizes", "cluster_share", "rejects", "critic_loss",
    "actor_loss", "q_mean", "batch_wait_s", "bad_batches", "policy_lag_request",
    "policy_lag_p50", "policy_lag_p95", "policy_lag_max", "sampled_moved_share",
    "buffer_moved_share",
]
"""`batch_wait_s` (written by the learner service): seconds of the epoch the update loop
waited for a batch, i.e. sampling and transport that prefetch did not hide. `bad_batches`: Batch
replies skipped so far because they failed validation. `policy_lag`: mean over recent episodes
of (their cycle in the lockstep schedule) − (the weights version they were acted with), 0 in
lockstep; `policy_lag_request`: the same against the weights version of the learner's latest
sample request when they were stored (the measure before the lockstep schedule existed).
`policy_lag_p50`, `_p95`, `_max`: the distribution of `policy_lag` over the episodes stored
during the epoch (nan when none was placed, e.g. right after a replay restart).
`sampled_moved_share`: the share of the epoch's sampled transitions whose episode's achieved
goal moved (the object, in the object tasks: hercs.replay_service.store.MOVED_THRESHOLD_M);
`buffer_moved_share`: that share among the replay's stored episodes, averaged over the
epoch's batches — what HER-CS and EBP exist to raise the first above."""


def read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a metrics.csv as strings by column (empty if no file)."""
    if not path.exists():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def recorded_epochs(path: Path) -> list[int]:
    """The epochs that metrics.csv holds rows for, in file order (empty if no file)."""
    return [int(row["epoch"]) for row in read_rows(path) if row.get("epoch")]


def truncate_metrics(path: Path, *, through_epoch: int) -> list[int]:
    """Drop the rows of epochs after `through_epoch` (a resumed learner trains them again),
    rewriting the file atomically; returns the epochs dropped."""
    if not path.exists():
        return []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        fields = reader.fieldnames or METRICS_COLUMNS
        rows = list(reader)
    keep = [r for r in rows if r.get("epoch") and int(r["epoch"]) <= through_epoch]
    dropped = [int(r["epoch"]) for r in rows if r not in keep and r.get("epoch")]
    if dropped or len(keep) != len(rows):
        tmp = path.with_suffix(".csv.tmp")
        with tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=fields)
            writer.writeheader()
            writer.writerows(keep)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    return dropped


class MetricsCsv:
    """runs/<run>/metrics.csv, one row per evaluated epoch, flushed per row."""

    def __init__(self, path: Path) -> None:
        self.path = path
        new = not path.exists() or path.stat().st_size == 0
        fields = METRICS_COLUMNS
        if not new:  # a resumed run keeps its file's columns (older runs may have fewer)
            with path.open(newline="") as f:
                fields = next(csv.reader(f), []) or METRICS_COLUMNS
        self._file = open(path, "a", newline="")  # noqa: SIM115 (closed in close())
        self._writer = csv.DictWriter(self._file, fieldnames=fields, extrasaction="ignore")
        if new:
            self._writer.writeheader()
            self._file.flush()

    def write(self, row: dict[str, Any]) -> None:
        self._writer.writerow(row)
        self._file.flush()

    def close(self) -> None:
        self._file.close()
