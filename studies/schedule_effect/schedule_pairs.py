"""Does asynchrony change the result? Each method's lockstep seeds against its asynchronous ones.

    python -m studies.schedule_effect           # every pair in the committed runs → docs/results/

Writes `<out>/asynchrony.md` (default docs/results/), which states the method, as a pure
function of the runs (no date, no commit) so that a test can check the committed file."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from hercs.apps.plots.curves import (
    Curve,
    aggregate,
    group,
    method_label,
    milestones,
)
from hercs.apps.plots.numbers import fixed, rate, signed_rate
from hercs.apps.sweep.cells import DONE_FILE
from studies.claims.claims import VERDICT_SEEDS
from studies.legacy_runs import LEGACY_LAG, LEGACY_NOTES
from studies.run_curves import load_runs
from studies.study_output import REPO, show_and_write

SCHEDULE_LABELS = {"lockstep": "lockstep", "async": "asynchronous"}
OUTPUT = "asynchrony.md"


@dataclass(frozen=True)
class SeedResult:
    """One run's numbers in a comparison."""

    run: str
    seed: int
    commit: str
    finished: str
    at_half: int | None
    success: float
    """The 10-epoch trailing mean after the pair's last common epoch."""


@dataclass(frozen=True)
class Difference:
    """lockstep − asynchronous at the pair's last common epoch."""

    value: float
    stderr: float | None
    low: float | None
    high: float | None
    rule: str

    @property
    def resolved(self) -> bool | None:
        if self.low is None or self.high is None:
            return None
        return self.low > 0.0 or self.high < 0.0


@dataclass(frozen=True)
class Comparison:
    task: str
    method: str  # the asynchronous key: her-cs, her-cs/bf16
    epoch: int
    lockstep: list[SeedResult]
    asynchronous: list[SeedResult]
    difference: Difference


def _done_record(run_dir: Path) -> dict[str, object]:
    try:
        return json.loads((run_dir / DONE_FILE).read_text())
    except (OSError, ValueError):
        return {}


def seed_result(curve: Curve, epoch: int) -> SeedResult:
    keep = curve.epochs <= epoch
    cut = Curve(curve.task, curve.method, curve.seed, curve.epochs[keep], curve.success[keep],
                curve.source)
    m = milestones(aggregate([cut]))  # one seed: its own trailing mean
    run_dir = Path(curve.source)
    done = _done_record(run_dir)
    assert m.final is not None
    return SeedResult(run_dir.name, curve.seed, str(done.get("commit", "–")),
                      str(done.get("finished", "–"))[:16].replace("T", " "),
                      m.crossing[0.5], m.final)


def difference(lockstep: Sequence[float], asynchronous: Sequence[float]) -> Difference:
    """Welch's t (or pooled when one side has one value) for mean(lockstep) − mean(async)."""
    a, b = np.asarray(lockstep, dtype=float), np.asarray(asynchronous, dtype=float)
    value = float(a.mean() - b.mean())
    na, nb = len(a), len(b)
    if na >= 2 and nb >= 2:
        va, vb = a.var(ddof=1) / na, b.var(ddof=1) / nb
        se = math.sqrt(va + vb)
        df = ((va + vb) ** 2 / (va ** 2 / (na - 1) + vb ** 2 / (nb - 1))
              if va + vb > 0 else float(na + nb - 2))
        rule = f"Welch, {fixed(df, 1)} degrees of freedom"
    elif na + nb >= 3:
        wide = a if na >= 2 else b
        se = math.sqrt(wide.var(ddof=1) * (1 / na + 1 / nb))
        df = float(len(wide) - 1)
        rule = f"one seed on one side: the other side's spread, {int(df)} degrees of freedom"
    else:
        return Difference(value, None, None, None, "one seed on each side: no spread to use")
    half = float(stats.t.ppf(0.975, df)) * se
    return Difference(value, se, value - half, value + half, rule)


def compare_all(curves: Sequence[Curve], max_epoch: int) -> list[Comparison]:
    """Every task × method × precision with runs in both schedules, in the tables' order."""
    out = []
    for task, methods in group(curves).items():
        for key, async_curves in methods.items():
            method, *variants = key.split("/")
            if "lockstep" in variants:
                continue
            # lockstep ignores the asynchronous lag settings: old and new defaults alike pair
            # with the lockstep runs of the same precision and environment (v1, a v4 weld
            # setting), whose key is theirs with /lockstep first (the order of
            # hercs.apps.plots.curves.method_key)
            partner = "/".join((method, "lockstep", *(v for v in variants if v != LEGACY_LAG)))
            lock_curves = methods.get(partner, [])
            if not lock_curves:
                continue
            both = [*lock_curves, *async_curves]
            epoch = min(max_epoch, *(int(c.epochs.max()) for c in both))
            lock = [seed_result(c, epoch) for c in sorted(lock_curves, key=lambda c: c.seed)]
            asy = [seed_result(c, epoch) for c in sorted(async_curves, key=lambda c: c.seed)]
            out.append(Comparison(task, key, epoch, lock, asy, difference(
                [s.success for s in lock], [s.success for s in asy])))
    return out


def _verdict(d: Difference, n: int) -> str:
    """claims.md's rule (studies/claims/claims.py `verdict`) for an interval of a difference,
    over `n` runs on the smaller side."""
    if not d.resolved:
        return "**a lead**: the interval includes 0"
    if n < VERDICT_SEEDS:
        return (f"**a lead**: the interval excludes 0, but from fewer than {VERDICT_SEEDS} runs "
                "a side")
    return (f"**a difference in these seeds**: the interval excludes 0, with {VERDICT_SEEDS} "
            "or more runs a side")


def report(comparisons: Sequence[Comparison], command: str, max_epoch: int = 50) -> str:
    lines = [
        "# Does asynchrony change the result? Lockstep against asynchronous runs", "",
        f"Drawn by `{command}` from the committed runs (docs/results/runs/; also `make "
        "figures`). Per run: the epoch its 10-epoch trailing mean of the test success first "
        "exceeds 0.5 (counted from 0, as in the Fig. 2 tables) and that mean after epoch E, "
        f"the last epoch every run of the comparison reached (at most {max_epoch}). The difference "
        "lockstep − asynchronous has a 95 % interval from Student's t. By claims.md's rule it "
        "is a *lead* where the interval includes 0 or a side has fewer than "
        f"{VERDICT_SEEDS} runs, and a *difference in these seeds* otherwise. Seeds are draws, "
        "not pairs: the runs come from different "
        "machines and commits (the table says which), and one seed gives other numbers on "
        "another CPU (docs/DESIGN.md §10).", ""]
    if not comparisons:
        lines += ["No task and method has runs in both schedules yet.", ""]
    for c in comparisons:
        title = f"{c.task} {method_label(c.method, LEGACY_NOTES)}"
        lines += [f"## {title}: lockstep against asynchronous, epoch {c.epoch}", "",
                  "| run | schedule | seed | trained with | finished (UTC) | epoch at 0.5 | "
                  f"success at {c.epoch} |", "|---|---|---|---|---|---|---|"]
        for schedule, seeds in (("lockstep", c.lockstep), ("async", c.asynchronous)):
            for s in seeds:
                at = "–" if s.at_half is None else str(s.at_half)
                lines.append(f"| {s.run} | {SCHEDULE_LABELS[schedule]} | {s.seed} | {s.commit} "
                             f"| {s.finished} | {at} | {rate(s.success)} |")
        lines += ["", f"| schedule | seeds | success at {c.epoch}, mean ± s.d. |",
                  "|---|---|---|"]
        for schedule, seeds in (("lockstep", c.lockstep), ("async", c.asynchronous)):
            values = np.array([s.success for s in seeds])
            sd = rate(values.std(ddof=1)) if len(values) > 1 else "–"
            lines.append(f"| {SCHEDULE_LABELS[schedule]} | {len(seeds)} | "
                         f"{rate(float(values.mean()))} ± {sd} |")
        d = c.difference
        if d.stderr is None or d.low is None or d.high is None:
            verdict = f"{signed_rate(d.value)}; {d.rule}."
        else:
            word = _verdict(d, min(len(c.lockstep), len(c.asynchronous)))
            verdict = (f"{signed_rate(d.value)}, standard error {rate(d.stderr)} ({d.rule}), 95 % "
                       f"interval [{signed_rate(d.low)}, {signed_rate(d.high)}]: {word}.")
        lines += ["", f"Lockstep − asynchronous after epoch {c.epoch}: {verdict}", ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=Path, default=REPO / "docs" / "results" / "runs")
    p.add_argument("--epoch", type=int, default=50,
                   help="compare after this epoch at most (default 50)")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "results")
    args = p.parse_args(argv)
    if args.epoch < 1:
        p.error(f"--epoch must be at least 1, got {args.epoch}")
    if not args.runs.is_dir():
        p.error(f"--runs {args.runs}: not a directory")
    curves = load_runs(args.runs)
    command = " ".join(["python -m studies.schedule_effect",
                        *(sys.argv[1:] if argv is None else argv)])
    text = report(compare_all(curves, args.epoch), command, args.epoch)
    show_and_write(args.out / OUTPUT, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
