"""`python -m studies.lag_audit`: docs/results/lag_audit.md from the committed runs.

Splits each resumed run's per-epoch policy lags where they jump (the whole-cycle shift of the
bug fixed in hercs/replay_service/policy_lag.py) and reports the lag each piece implies. The bug
and the method: docs/FAULTS.md ("the policy lag through a restart") and docs/results/lag_audit.md.
"""

from __future__ import annotations

import argparse
import csv
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml

from studies.claims.claim_runs import lag_setting
from studies.study_output import REPO, show_and_write

RESULTS = REPO / "docs" / "results"
JUMP = 1.5
"""A change of the per-epoch p50 larger than this starts a new piece (a resume's shift is a
whole number of cycles; within a piece the p50 moves by at most 1)."""


@dataclass(frozen=True)
class Piece:
    first: int
    last: int
    p50: float  # median of the per-epoch p50s
    mean: float  # mean of the per-epoch means
    max: float  # largest per-epoch max
    # mean and max leave out the first epoch of a longer piece: a resume's epoch holds lags
    # of both lives


def lag_rows(run: Path) -> list[tuple[int, float, float, float]]:
    """(epoch, mean, p50, max) of every epoch that recorded a lag distribution."""
    with (run / "metrics.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    out = []
    for r in rows:
        try:
            out.append((int(r["epoch"]), float(r["policy_lag"]), float(r["policy_lag_p50"]),
                        float(r["policy_lag_max"])))
        except (KeyError, TypeError, ValueError):
            continue
    return [row for row in out if row[2] == row[2]]  # an epoch with no lag has p50 nan


def pieces(rows: list[tuple[int, float, float, float]]) -> list[Piece]:
    out: list[list[tuple[int, float, float, float]]] = []
    for row in rows:
        if out and abs(row[2] - out[-1][-1][2]) <= JUMP:
            out[-1].append(row)
        else:
            out.append([row])
    return [Piece(p[0][0], p[-1][0], statistics.median(r[2] for r in p),
                  statistics.fmean(r[1] for r in (p[1:] or p)), max(r[3] for r in (p[1:] or p)))
            for p in out]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.lag_audit",
                                     description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--runs", type=Path, default=RESULTS / "runs")
    parser.add_argument("-o", "--output", type=Path, default=RESULTS / "lag_audit.md")
    args = parser.parse_args(argv)
    runs: dict[str, tuple[str, int, list[tuple[int, float, float, float]]]] = {}
    for run in sorted(p for p in args.runs.iterdir() if (p / "metrics.csv").is_file()):
        config = yaml.safe_load((run / "config.yaml").read_text()) or {}
        if (config.get("training") or {}).get("schedule", "async") != "async":
            continue
        rows = lag_rows(run)
        if rows:
            bound = int((config.get("training") or {}).get("max_policy_lag", -1) or -1)
            runs[run.name] = (lag_setting(config), bound, rows)
    reference: dict[str, float] = {}
    for setting in {s for s, _, _ in runs.values()}:
        clean = [r[2] for s, _, rows in runs.values() if s == setting
                 and min(r[1] for r in rows) >= 0 for r in rows]
        if clean:
            reference[setting] = statistics.median(clean)
    lines = ["# Policy lag recorded after a resume, and the lag it implies", "",
             "Written by `python -m studies.lag_audit` from docs/results/runs (asynchronous "
             "runs with a per-epoch lag distribution). A run listed here recorded a lag shifted "
             "by a whole number of cycles from a resume on (the bug fixed in "
             "hercs/replay_service/policy_lag.py); *implied* is recorded + shift, the shift "
             "taken from the median p50 of the runs of the same lag setting that never read a "
             "negative lag. A piece's mean and max leave out its first epoch, where the two lives "
             "mix.", "",
             "| run | epochs | recorded mean / p50 / max | shift | implied mean / max | "
             "bound |", "|---|---|---|---|---|---|"]
    shifted_runs = 0
    for name, (setting, bound, rows) in runs.items():
        if setting not in reference:
            continue
        # only a piece reading lower than the reference is the bug's; one reading higher is
        # lag that happened (a learner restarted from an older checkpoint, in the chaos runs)
        parts = [(p, max(0, round(reference[setting] - p.p50))) for p in pieces(rows)]
        if all(shift == 0 for _, shift in parts):
            continue
        shifted_runs += 1
        for p, shift in parts:
            lines.append(f"| {name} | {p.first}–{p.last} | {p.mean:.1f} / {p.p50:g} / "
                         f"{p.max:g} | {shift:+d} | {p.mean + shift:.1f} / {p.max + shift:g} | "
                         f"{bound if bound > 0 else 'none'} |")
    lines += ["", f"{shifted_runs} runs recorded a shifted lag; every other asynchronous run's "
              "lag needs no correction.", ""]
    show_and_write(args.output, "\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
