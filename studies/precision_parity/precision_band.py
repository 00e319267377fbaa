"""Does the learner's bf16 mode learn like fp32? A method's bf16 seeds against its fp32 seeds.

    python -m studies.precision_parity          # FetchPush HER-EBP-CS, epochs 1–40, committed runs

Writes `<out>/bf16_parity.{md,png}` (default docs/results/), which states the band and the rule;
discussed in docs/PERFORMANCE.md §4."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from hercs.apps.plots.curves import (
    Curve,
    PlotError,
    aggregate,
    group,
    method_key,
    method_label,
    milestones,
    moving_average,
    task_title,
)
from hercs.apps.plots.figures import plot_figure
from studies.legacy_runs import LEGACY_LAG, LEGACY_NOTES
from studies.run_curves import load_runs
from studies.study_output import REPO, git_commit


@dataclass(frozen=True)
class SeedParity:
    """One bf16 seed against the fp32 band."""

    seed: int
    inside: int
    above: int
    """Epochs above the band (learning faster than every fp32 seed); the rest are below."""
    compared: int
    at_half: int | None
    at_ninety: int | None
    final: float

    @property
    def share_inside(self) -> float:
        return self.inside / self.compared


def smoothed(curve: Curve, epochs: np.ndarray) -> np.ndarray:
    """The curve's trailing mean at `epochs` (which it must all have)."""
    ma = moving_average(curve.epochs, curve.success)
    lookup = dict(zip(curve.epochs.tolist(), ma.tolist(), strict=True))
    return np.array([lookup[int(e)] for e in epochs])


def compare(fp32: Sequence[Curve], bf16: Sequence[Curve], last_epoch: int
            ) -> tuple[np.ndarray, list[SeedParity]]:
    """Epochs compared (1..E, every run has them) and each bf16 seed's parity."""
    if not fp32 or not bf16:
        raise PlotError(f"need fp32 and bf16 runs (got {len(fp32)} and {len(bf16)})")
    common = set.intersection(*(set(c.epochs.tolist()) for c in (*fp32, *bf16)))
    epochs = np.array(sorted(e for e in common if e <= last_epoch), dtype=int)
    if len(epochs) == 0:
        raise PlotError("the fp32 and bf16 runs share no epoch")
    band = np.stack([smoothed(c, epochs) for c in fp32])
    low, high = band.min(axis=0) - 1e-9, band.max(axis=0) + 1e-9
    seeds = []
    for curve in sorted(bf16, key=lambda c: c.seed):
        ma = smoothed(curve, epochs)
        m = milestones(aggregate([_cut(curve, epochs)]))
        seeds.append(SeedParity(curve.seed, int(((ma >= low) & (ma <= high)).sum()),
                                int((ma > high).sum()), len(epochs), m.crossing[0.5],
                                m.crossing[0.9], float(ma[-1])))
    return epochs, seeds


def _cut(curve: Curve, epochs: np.ndarray) -> Curve:
    keep = np.isin(curve.epochs, epochs)
    return Curve(curve.task, curve.method, curve.seed, curve.epochs[keep], curve.success[keep],
                 curve.source)


def load_pair(runs: Path, task: str, method: str) -> tuple[list[Curve], list[Curve]]:
    """(fp32 seeds, bf16 seeds) of one task and method in the asynchronous schedule: those of
    the current default where both precisions have runs of it, else those of the old, staler
    default (`studies.legacy_runs.LEGACY_LAG`), never one of each."""
    title = task_title(task)
    mine = group(c for c in load_runs(runs) if c.task == title).get(title, {})
    for lag in ("", LEGACY_LAG):
        pair = (mine.get(method_key(method, variant=lag), []),
                mine.get(method_key(method, precision="bf16", variant=lag), []))
        if all(pair):
            return pair
    return [], []


def report(fp32: Sequence[Curve], bf16: Sequence[Curve], *, last_epoch: int, tolerance: float,
           command: str) -> tuple[str, bool]:
    epochs, seeds = compare(fp32, bf16, last_epoch)
    passed = all(s.share_inside >= 1.0 - tolerance for s in seeds)
    ref = milestones(aggregate([_cut(c, epochs) for c in fp32]))
    title, method = fp32[0].task, method_label(fp32[0].method, LEGACY_NOTES)

    def fmt(v: int | None) -> str:
        return "–" if v is None else str(v)

    lines = [
        f"# bf16 against fp32: {title} {method}, epochs {epochs[0]}–{epochs[-1]}", "",
        f"`{command}` — {datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}, "
        f"commit {git_commit()}.", "",
        f"Band: min–max of the {len(fp32)} fp32 seeds' 10-epoch trailing means "
        f"(seeds {', '.join(str(c.seed) for c in sorted(fp32, key=lambda c: c.seed))}); "
        "a bf16 seed is inside at an epoch when its own trailing mean is within it.", "",
        "![bf16 against fp32](bf16_parity.png)", "",
        "| run | epochs inside the fp32 band | above | below | epoch at 0.5 | epoch at 0.9 | "
        f"success at {epochs[-1]} |",
        "|---|---|---|---|---|---|---|",
        f"| fp32, mean of {len(fp32)} seeds | – | – | – | {fmt(ref.crossing[0.5])} | "
        f"{fmt(ref.crossing[0.9])} | {ref.final:.2f} |",
    ]
    for s in seeds:
        below = s.compared - s.inside - s.above
        lines.append(f"| bf16 seed {s.seed} | {s.inside}/{s.compared} ({s.share_inside:.0%}) | "
                     f"{s.above} | {below} | {fmt(s.at_half)} | {fmt(s.at_ninety)} | "
                     f"{s.final:.2f} |")
    verdict = ("inside the fp32 band" if passed else "outside the fp32 band")
    lines += ["", f"Verdict: the bf16 seeds are **{verdict}** (rule: every seed inside at "
                  f"≥ {1 - tolerance:.0%} of the epochs)."]
    return "\n".join(lines) + "\n", passed


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=Path, default=REPO / "docs" / "results" / "runs")
    p.add_argument("--task", default="push")
    p.add_argument("--method", default="her-ebp-cs")
    p.add_argument("--epochs", type=int, default=40, help="compare epochs 1..N (default 40)")
    p.add_argument("--tolerance", type=float, default=0.1,
                   help="share of epochs a seed may spend outside the band (default 0.1)")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "results")
    args = p.parse_args(argv)
    if not 0.0 <= args.tolerance < 1.0:
        p.error(f"--tolerance must be in [0, 1), got {args.tolerance}")
    command = "python -m studies.precision_parity " + " ".join(
        sys.argv[1:] if argv is None else argv)
    try:
        fp32, bf16 = load_pair(args.runs, args.task, args.method)
        text, passed = report(fp32, bf16, last_epoch=args.epochs, tolerance=args.tolerance,
                              command=command.strip())
    except PlotError as exc:
        print(f"precision_parity: {exc}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    shown = np.arange(1, args.epochs + 1)
    plot_figure({task_title(args.task): {
        method_key(args.method): [_cut(c, shown) for c in fp32],
        method_key(args.method, precision="bf16"): [_cut(c, shown) for c in bf16]}},
        args.out / "bf16_parity.png", band="minmax")  # the rule's band
    (args.out / "bf16_parity.md").write_text(text)
    print(text, end="")
    print(f"wrote {args.out / 'bf16_parity.md'} and {args.out / 'bf16_parity.png'} "
          f"({'inside' if passed else 'outside'} the band)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
