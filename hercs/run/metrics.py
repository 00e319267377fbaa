"""A run's `metrics.csv` (hercs.run.rundir.METRICS): its columns, the learner's writer, and the
readers that services, apps and benchmarks share. One row per evaluated epoch; a resumed run
keeps its file's columns (older runs may have fewer)."""

from __future__ import annotations

import csv
import io
import os
import shutil
from pathlib import Path
from typing import Any

from hercs.errors import HercsError

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


def parse_table(text: str) -> tuple[list[str], list[dict[str, str]]]:
    """metrics.csv's text as its header and its rows, cells as strings by column (a row's
    fields past the header under the key None, as csv.DictReader gives them). The one parse
    of the file: every reader of metrics.csv (the Python API, hercs plot, the trackers, the
    learner's resume) goes through it."""
    reader = csv.DictReader(io.StringIO(text, newline=""))
    rows = list(reader)
    return list(reader.fieldnames or ()), rows


def read_table(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    """`parse_table` of the file at `path` ([], [] if there is none)."""
    if not path.exists():
        return [], []
    with path.open(newline="") as f:
        return parse_table(f.read())


def read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a metrics.csv as strings by column (empty if no file)."""
    return read_table(path)[1]


def recorded_epochs(path: Path) -> list[int]:
    """The epochs that metrics.csv holds rows for, in file order (empty if no file)."""
    return [int(row["epoch"]) for row in read_rows(path) if row.get("epoch")]


class MetricsFileError(HercsError):
    """A metrics.csv is not whole (cut short, a row malformed, an epoch twice); the message
    names the file, what is wrong and where."""


def checked_epochs(path: Path) -> list[int]:
    """The epochs metrics.csv holds rows for, in file order, after checking the whole file
    (empty if no file, or a header alone). Raises `MetricsFileError` for a file cut short
    (its last row without its line end, or a row with other than the header's number of
    fields), a row whose epoch is not an integer >= 1, or an epoch recorded twice (two
    learners wrote the file)."""
    if not path.exists():
        return []
    text = path.read_text(errors="replace")
    if not text:
        return []
    if not text.endswith("\n"):
        raise MetricsFileError(f"{path}: cut short: its last line has no line end (a write "
                               "was interrupted, or the file was truncated)")
    rows = list(csv.reader(io.StringIO(text, newline="")))
    header, body = rows[0], rows[1:]
    if "epoch" not in header:
        raise MetricsFileError(f"{path}: no 'epoch' column in its first line; not a hercs "
                               "metrics.csv, or its header was lost")
    column = header.index("epoch")
    epochs: list[int] = []
    for line, row in enumerate(body, start=2):
        if len(row) != len(header):
            raise MetricsFileError(f"{path}, line {line}: {len(row)} fields where the header "
                                   f"has {len(header)} (a row cut short or damaged)")
        try:
            epoch = int(row[column])
        except ValueError:
            epoch = 0
        if epoch < 1:
            raise MetricsFileError(f"{path}, line {line}: epoch {row[column]!r}, not an "
                                   "integer >= 1")
        epochs.append(epoch)
    twice = sorted({e for e in epochs if epochs.count(e) > 1})
    if twice:
        raise MetricsFileError(f"{path}: epochs {epoch_spans(twice)} recorded more than once (two "
                               "runs wrote into this folder at the same time?)")
    return epochs


def epoch_spans(epochs: list[int]) -> str:
    """[1, 2, 3, 7] → '1..3, 7'."""
    spans: list[list[int]] = []
    for epoch in sorted(epochs):
        if spans and epoch == spans[-1][1] + 1:
            spans[-1][1] = epoch
        else:
            spans.append([epoch, epoch])
    return ", ".join(f"{a}..{b}" if b > a else f"{a}" for a, b in spans)


def truncate_metrics(path: Path, *, through_epoch: int, aside: Path) -> list[int]:
    """Drop the rows of epochs after `through_epoch` (a resumed learner trains them again),
    rewriting the file atomically, after copying the whole old file to `aside/metrics.csv`
    (made only then): rows are never lost. Returns the epochs dropped."""
    if not path.exists():
        return []
    header, rows = read_table(path)
    fields = header or METRICS_COLUMNS
    keep = [r for r in rows if r.get("epoch") and int(r["epoch"]) <= through_epoch]
    dropped = [int(r["epoch"]) for r in rows if r not in keep and r.get("epoch")]
    if dropped or len(keep) != len(rows):
        aside.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, aside / path.name)
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
            fields = read_table(path)[0] or METRICS_COLUMNS
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
