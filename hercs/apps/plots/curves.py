"""Learning curves and milestone tables from run directories (`hercs plot`), beside the
authors' published per-seed results (data/authors_success_rates.csv, a copy of
docs/reference/'s), as pure functions over numbers (the table rule: docs/DESIGN.md §5);
tables.py writes the tables, figures.py draws. Runs in another setting (lockstep, bf16,
Fetch*-v1, another lag…: series.py) are groups of their own, never averaged with the default's.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

# the series' vocabulary, importable from here as before it had its own module
from hercs.apps.plots.series import ENV_VERSION_DEFAULT as ENV_VERSION_DEFAULT
from hercs.apps.plots.series import EPSILON_UNMARKED as EPSILON_UNMARKED
from hercs.apps.plots.series import VariantOf as VariantOf
from hercs.apps.plots.series import energy_epsilon as energy_epsilon
from hercs.apps.plots.series import marks_epsilon as marks_epsilon
from hercs.apps.plots.series import method_key as method_key
from hercs.apps.plots.series import method_label as method_label
from hercs.apps.plots.series import method_rank as method_rank
from hercs.apps.plots.series import series_key
from hercs.apps.plots.style import METHOD_COLORS as METHOD_COLORS
from hercs.errors import HercsError
from hercs.run.metrics import read_table
from hercs.run.rundir import RunDir

REFERENCE_CSV = Path(__file__).resolve().parent / "data" / "authors_success_rates.csv"

TASK_TITLES: dict[str, str] = {
    "reach": "FetchReach", "push": "FetchPush", "pick": "FetchPickAndPlace",
    "slide": "FetchSlide",
}
WINDOW = 10
THRESHOLDS: tuple[float, ...] = (0.5, 0.9)
AT_EPOCHS: tuple[int, ...] = (50, 100, 200)
_EPS = 1e-9  # "exceeds": float noise around an exact tie (e.g. 25/50) does not count

# Figure geometry: `hercs plot`'s PNG is exactly ((PANEL_W + LEGEND_W) * panels) x PANEL_H
# inches at DPI, the legend beside each panel; Fig. 2's (PANEL_W * 3) x (PANEL_H * 2).
PANEL_W, PANEL_H, DPI = 5.0, 4.0, 100
LEGEND_W = 3.2
BANDS: tuple[str, ...] = ("ci", "minmax", "both")
DEFAULT_BAND = "ci"  # a dozen curves' min–max bands cover one another; `--band both` adds them
CI_LEVEL = 0.95
CI_REPS = 2000
CI_SEED = 0


class PlotError(HercsError):
    """A run directory or reference file cannot be read; the message names it."""


@dataclass(frozen=True)
class Curve:
    """One seed's test success rate per epoch."""

    task: str  # display name, e.g. "FetchPush"
    method: str
    seed: int
    epochs: np.ndarray  # int, increasing
    success: np.ndarray  # float, same length
    source: str = ""


@dataclass(frozen=True)
class Aggregate:
    """Seed statistics per epoch, over the epochs every seed reached."""

    epochs: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    n_seeds: int


@dataclass(frozen=True)
class Milestones:
    crossing: dict[float, int | None] = field(default_factory=dict)
    at: dict[int, float | None] = field(default_factory=dict)
    n_seeds: int = 0
    n_epochs: int = 0
    final: float | None = None  # the moving average at the last common epoch


# ---------------------------------------------------------------------------------- loading

def task_title(name: str) -> str:
    return TASK_TITLES.get(name, name)


def _curve(task: str, method: str, seed: int, points: dict[int, float], source: str) -> Curve:
    epochs = np.array(sorted(points), dtype=int)
    return Curve(task, method, seed, epochs, np.array([points[e] for e in epochs], dtype=float),
                 source)


def load_run(run_dir: str | Path, variant_of: VariantOf | None = None) -> Curve:
    """`config.yaml` (task.name, run.method, run.seed; the variants of `method_key`, with the
    caller's own from `variant_of`) and `metrics.csv` (epoch, success_rate) of one run
    directory. A repeated epoch keeps its last row."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise PlotError(f"{run_dir}: not a run directory")
    config_path, metrics_path = RunDir(run_dir).config, RunDir(run_dir).metrics
    for path in (config_path, metrics_path):
        if not path.is_file():
            raise PlotError(f"{run_dir}: no {path.name} in this run directory")
    try:
        config = yaml.safe_load(config_path.read_text()) or {}
        task = config["task"]["name"]
        seed = int(config["run"]["seed"])
        method = series_key(config, variant_of)
    except (yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise PlotError(f"{config_path}: needs task.name, run.method and run.seed ({exc!r})"
                        ) from exc
    points: dict[int, float] = {}
    header, rows = read_table(metrics_path)
    missing = {"epoch", "success_rate"} - set(header)
    if missing:
        raise PlotError(f"{metrics_path}: missing column(s) {sorted(missing)}")
    for line, row in enumerate(rows, start=2):
        try:
            points[int(row["epoch"])] = float(row["success_rate"])
        except (TypeError, ValueError) as exc:
            raise PlotError(f"{metrics_path}:{line}: bad epoch/success_rate") from exc
    if not points:
        raise PlotError(f"{metrics_path}: no epochs yet")
    return _curve(task_title(task), method, seed, points, str(run_dir))


def load_reference(path: str | Path = REFERENCE_CSV) -> list[Curve]:
    """The authors' curves: columns task, method, seed, epoch, success_rate."""
    path = Path(path)
    if not path.is_file():
        raise PlotError(f"{path}: reference CSV not found")
    series: dict[tuple[str, str, int], dict[int, float]] = {}
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            key = (row["task"], row["method"], int(row["seed"]))
            series.setdefault(key, {})[int(row["epoch"])] = float(row["success_rate"])
    return [_curve(t, m, s, pts, str(path)) for (t, m, s), pts in sorted(series.items())]


def group(curves: Iterable[Curve], notes: list[str] | None = None
          ) -> dict[str, dict[str, list[Curve]]]:
    """task → method → one curve per seed, methods in the paper's order (unknown ones last).

    Runs of the same task, method and seed are one seed, not several: the one with the most
    epochs is kept (a note in `notes` names the others)."""
    by_seed: dict[tuple[str, str, int], Curve] = {}
    repeats: list[str] = []
    for c in curves:
        key = (c.task, c.method, c.seed)
        kept = by_seed.get(key)
        if kept is not None:
            longer, other = (c, kept) if len(c.epochs) > len(kept.epochs) else (kept, c)
            repeats.append(f"{other.source or 'a run'} (as {longer.source or 'another'})")
            c = longer
        by_seed[key] = c
    if repeats and notes is not None:  # one line, however many: a list would bury the rest
        notes.append(f"{len(repeats)} run{'s' if len(repeats) != 1 else ''} with the same "
                     "task, series and seed as another, counted once, with the longer run: "
                     + ", ".join(repeats))
    out: dict[str, dict[str, list[Curve]]] = {}
    for c in by_seed.values():
        out.setdefault(c.task, {}).setdefault(c.method, []).append(c)
    return {t: dict(sorted(ms.items(), key=lambda kv: method_rank(kv[0])))
            for t, ms in out.items()}


# ------------------------------------------------------------------------------ arithmetic

def aggregate(curves: Sequence[Curve], *, every_seed: bool = True) -> Aggregate:
    """Mean, min and max across seeds at each epoch that every seed reached (the table's
    rule), or with `every_seed=False` at each epoch any seed reached, over the seeds that
    reached it (the figure: each run is drawn to its end)."""
    if not curves:
        raise ValueError("aggregate needs at least one curve")
    tables = [dict(zip(c.epochs.tolist(), c.success.tolist(), strict=True)) for c in curves]
    epoch_sets = [set(t) for t in tables]
    chosen = set.intersection(*epoch_sets) if every_seed else set.union(*epoch_sets)
    epochs = np.array(sorted(chosen), dtype=int)
    rows = [[t[e] for t in tables if e in t] for e in epochs]
    return Aggregate(epochs, np.array([np.mean(r) for r in rows], dtype=float).reshape(-1),
                     np.array([min(r) for r in rows], dtype=float).reshape(-1),
                     np.array([max(r) for r in rows], dtype=float).reshape(-1), len(curves))


def moving_average(epochs: np.ndarray, values: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """Trailing mean at each epoch e over the available epochs in [e - window + 1, e]."""
    epochs, values = np.asarray(epochs), np.asarray(values, dtype=float)
    return np.array([values[(epochs > e - window) & (epochs <= e)].mean() for e in epochs])


@dataclass(frozen=True)
class Bands:
    """Per epoch, over the seeds that reached it, statistics of the seeds' own 10-epoch
    moving averages: their mean, the bootstrap interval of that mean, their min and max."""

    epochs: np.ndarray
    mean: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    low: np.ndarray
    high: np.ndarray
    n_seeds: int


def seed_bands(curves: Sequence[Curve], rng: np.random.Generator, *, window: int = WINDOW,
               reps: int = CI_REPS, level: float = CI_LEVEL, every_seed: bool = False) -> Bands:
    """The figure's bands (docs/DESIGN.md §6, "Figures"). The interval is the percentile interval of
    the mean over `reps` resamples of the seeds, drawn with replacement; one draw of seed
    indices serves every epoch that the same seeds reached, so the band is as smooth as the
    curves. With one seed the interval and the min–max are the curve itself."""
    if not curves:
        raise ValueError("seed_bands needs at least one curve")
    smoothed = [dict(zip(c.epochs.tolist(), moving_average(c.epochs, c.success, window).tolist(),
                         strict=True)) for c in curves]
    sets = [set(t) for t in smoothed]
    epochs = np.array(sorted(set.intersection(*sets) if every_seed else set.union(*sets)),
                      dtype=int)
    tail = (1.0 - level) / 2.0 * 100.0
    draws: dict[tuple[int, ...], np.ndarray] = {}
    out = np.empty((5, len(epochs)))
    for i, e in enumerate(epochs.tolist()):
        present = tuple(k for k, t in enumerate(smoothed) if e in t)
        values = np.array([smoothed[k][e] for k in present])
        if present not in draws:
            draws[present] = rng.integers(0, len(present), size=(reps, len(present)))
        low, high = np.percentile(values[draws[present]].mean(axis=1), [tail, 100.0 - tail])
        out[:, i] = values.mean(), low, high, values.min(), values.max()
    mean, ci_low, ci_high, low, high = out
    return Bands(epochs, mean, ci_low, ci_high, low, high, len(curves))


def milestones(agg: Aggregate, thresholds: Sequence[float] = THRESHOLDS,
               at_epochs: Sequence[int] = AT_EPOCHS, window: int = WINDOW) -> Milestones:
    """docs/DESIGN.md §5's numbers for one aggregated method (the rule is there)."""
    ma = moving_average(agg.epochs, agg.mean, window)
    crossing: dict[float, int | None] = {}
    for t in thresholds:
        hit = np.nonzero(ma > t + _EPS)[0]
        crossing[t] = int(agg.epochs[hit[0]]) - 1 if len(hit) else None
    lookup = dict(zip(agg.epochs.tolist(), ma.tolist(), strict=True))
    return Milestones(crossing, {e: lookup.get(e) for e in at_epochs}, agg.n_seeds,
                      len(agg.epochs), float(ma[-1]) if len(ma) else None)
