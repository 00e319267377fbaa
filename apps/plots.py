"""Learning curves and milestone tables from run directories (`hercs plot`), optionally next
to the authors' published per-seed results (`docs/reference/authors_success_rates.csv`).

Everything except `plot_figure` is a pure function over numbers, so the tests pin the curves
and the table without drawing.

Table rule (the one that reproduces docs/DESIGN.md §5 from the authors' CSV exactly):

* seeds are aggregated over the epochs that *every* seed of the group reached (a seed that
  stopped at epoch 125 cuts the group at 125, so "success at epoch 200" is "–");
* the smoothed curve is the trailing 10-epoch moving average of the seed mean, the mean of
  epochs max(1, e-9)..e;
* "epoch at 0.5 / 0.9" is the first epoch whose moving average *exceeds* the threshold,
  numbered from 0 as in the authors' (OpenAI baselines) logs, i.e. the number of epochs
  completed before it. Counting from 1 or accepting equality would give docs/DESIGN.md §5 + 1
  (Push HER reaches exactly 0.500 at its 55th epoch, and §5 says 55, not 54);
* "success at 50 / 100 / 200" is the moving average after the 50th / 100th / 200th epoch.

Figure rule: each method's 10-epoch moving average of the seed mean (solid) and bands over the
seeds' own 10-epoch moving averages (`seed_bands`; `--band ci|minmax|both`): the bootstrap 95 %
interval of their mean (resampling seeds, a fixed RNG seed; the default) and/or, lighter, their
min–max; the authors' curves dashed, smoothed alike. Every run is drawn to its own end (at each
epoch, over the seeds that reached it); the legend sits beside the panel, not over the curves.
Runs with the same task, method and seed are one seed (the longest is kept, with a note on
stderr); a folder named twice on the command line is read once. A run trained in the lockstep
schedule (`training.schedule`) is its own method, `<method>/lockstep` ("HER-CS lockstep"), so
that it is compared with the asynchronous runs instead of averaged into them; likewise a run
whose learner ran in bf16 (`learner.precision`) is `<method>/bf16`, and a run on the authors'
Fetch*-v1 (`task.env_version`) is `<method>/v1` ("HER-CS (v1)"), never averaged with v4 runs.
Fig. 2 draws the paper's methods, their lockstep variants and their v1 runs, not the precision
variants (a speed option, compared in docs/PERFORMANCE.md).
"""

from __future__ import annotations

import csv
import math
import sys
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hercs.errors import HercsError
from hercs.methods import METHODS

REFERENCE_CSV = (Path(__file__).resolve().parents[1] / "docs" / "reference"
                 / "authors_success_rates.csv")

TASK_TITLES: dict[str, str] = {
    "reach": "FetchReach", "push": "FetchPush", "pick": "FetchPickAndPlace",
    "slide": "FetchSlide",
}
METHOD_ORDER: tuple[str, ...] = tuple(METHODS)
METHOD_LABELS: dict[str, str] = {name: method.label for name, method in METHODS.items()}
METHOD_COLORS: dict[str, str] = {
    "her": "tab:blue", "her-cs": "tab:red", "her-ebp": "tab:green", "her-ebp-cs": "tab:orange",
}
VARIANT_COLORS: dict[str, str] = {
    "her/lockstep": "tab:cyan", "her-cs/lockstep": "tab:purple",
    "her-ebp/lockstep": "tab:olive", "her-ebp-cs/lockstep": "tab:brown",
    "her/bf16": "tab:gray", "her-cs/bf16": "tab:pink",
    "her-ebp/bf16": "darkgreen", "her-ebp-cs/bf16": "goldenrod",
    "her/lockstep/bf16": "slategray", "her-cs/lockstep/bf16": "darkmagenta",
    "her-ebp/lockstep/bf16": "yellowgreen", "her-ebp-cs/lockstep/bf16": "darkslateblue",
    "her/v1": "navy", "her-cs/v1": "darkred", "her-ebp/v1": "seagreen",
    "her-ebp-cs/v1": "chocolate",
    "her/lag7": "lightsteelblue", "her-cs/lag7": "lightcoral", "her-ebp/lag7": "lightgreen",
    "her-ebp-cs/lag7": "burlywood", "her-ebp-cs/bf16/lag7": "khaki",
}
ENV_VERSION_DEFAULT = "v4"
"""`task.env_version` of a run whose config.yaml has none (written before v1 existed)."""
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


def method_key(method: str, schedule: str = "async", precision: str = "fp32",
               env_version: str = ENV_VERSION_DEFAULT, lag: str = "",
               torquescale: float = 1.0) -> str:
    """How runs are grouped: the method, with `/lockstep` for the lockstep schedule, `/bf16`
    for the learner's mixed precision, `/lag7` for an asynchronous run made with the old,
    staler default (`lag`, see `legacy_lag`) and `/v1` for the authors' Fetch*-v1
    environment, or `/ts4` for v4 with the gripper weld's torquescale 4
    (`her-cs/lockstep/bf16/v1` has three)."""
    env = env_version if torquescale == 1.0 else f"ts{torquescale:g}"
    variants = (v for v, default in ((schedule, "async"), (precision, "fp32"), (lag, ""),
                                     (env, ENV_VERSION_DEFAULT)) if v != default)
    return "/".join((method, *variants))


LEGACY_LAG = "lag7"
"""The variant of asynchronous runs made before the lag sources were settings (2026-11-25):
rate tolerance 80, two batches prefetched plus one held, two episodes queued per actor, a
policy lag of 7 cycles (docs/results/lag_sources_beside.md) against 2–3 since."""


def legacy_lag(config: dict[str, Any]) -> str:
    """`LEGACY_LAG` for an asynchronous run whose resolved config.yaml (one with a `replay`
    section, as every run saves) predates `learner.prefetch_depth`, else ""."""
    schedule = (config.get("training") or {}).get("schedule", "async")
    resolved = "rate_tolerance_updates" in (config.get("replay") or {})
    new = "prefetch_depth" in (config.get("learner") or {})
    return LEGACY_LAG if schedule == "async" and resolved and not new else ""


def _env_version(variant: str) -> bool:
    return variant in ("v1", ENV_VERSION_DEFAULT) or variant.startswith("ts")


def method_label(key: str) -> str:
    """`her-cs` → "HER-CS", `her-cs/lockstep` → "HER-CS lockstep", `her-cs/v1` →
    "HER-CS (v1)", `her-cs/lag7` → "HER-CS (lag 7)"."""
    method, *variants = key.split("/")
    inline = (v for v in variants if not _env_version(v) and v != LEGACY_LAG)
    label = " ".join((METHOD_LABELS.get(method, method), *inline))
    notes = [f"torquescale {v[2:]}" if v.startswith("ts") else v
             for v in variants if _env_version(v)]
    if LEGACY_LAG in variants:
        notes.append("lag 7")
    return "".join((label, *(f" ({v})" for v in notes)))


def method_color(key: str) -> str | None:
    """A colour per method and variant; a v1 combination without its own colour takes its
    v4 twin's (the label tells them apart)."""
    color = METHOD_COLORS.get(key) or VARIANT_COLORS.get(key)
    method, *variants = key.split("/")
    if color is None and variants and _env_version(variants[-1]):
        return method_color("/".join((method, *variants[:-1])))
    return color


def method_linestyle(key: str) -> str | tuple[int, tuple[int, ...]]:
    """Our curves: solid, a lockstep variant dash-dotted, a bf16 one dotted (the authors'
    are dashed), so that variants read apart where their colours are close."""
    variants = key.split("/")[1:]
    if "lockstep" in variants:
        return (0, (5, 1, 1, 1, 1, 1)) if "bf16" in variants else "-."
    return ":" if "bf16" in variants else "-"


def _curve(task: str, method: str, seed: int, points: dict[int, float], source: str) -> Curve:
    epochs = np.array(sorted(points), dtype=int)
    return Curve(task, method, seed, epochs, np.array([points[e] for e in epochs], dtype=float),
                 source)


def load_run(run_dir: str | Path) -> Curve:
    """`config.yaml` (task.name, run.method, run.seed; the variants of `method_key`) and
    `metrics.csv` (epoch, success_rate) of one run directory. A repeated epoch keeps its last
    row."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise PlotError(f"{run_dir}: not a run directory")
    config_path, metrics_path = run_dir / "config.yaml", run_dir / "metrics.csv"
    for path in (config_path, metrics_path):
        if not path.is_file():
            raise PlotError(f"{run_dir}: no {path.name} in this run directory")
    try:
        config = yaml.safe_load(config_path.read_text()) or {}
        task, method = config["task"]["name"], config["run"]["method"]
        seed = int(config["run"]["seed"])
        method = method_key(method, (config.get("training") or {}).get("schedule", "async"),
                            (config.get("learner") or {}).get("precision", "fp32"),
                            config["task"].get("env_version", ENV_VERSION_DEFAULT),
                            legacy_lag(config),
                            float(config["task"].get("weld_torquescale", 1.0)))
    except (yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise PlotError(f"{config_path}: needs task.name, run.method and run.seed ({exc!r})"
                        ) from exc
    points: dict[int, float] = {}
    with metrics_path.open(newline="") as f:
        reader = csv.DictReader(f)
        missing = {"epoch", "success_rate"} - set(reader.fieldnames or ())
        if missing:
            raise PlotError(f"{metrics_path}: missing column(s) {sorted(missing)}")
        for line, row in enumerate(reader, start=2):
            try:
                points[int(row["epoch"])] = float(row["success_rate"])
            except (TypeError, ValueError) as exc:
                raise PlotError(f"{metrics_path}:{line}: bad epoch/success_rate") from exc
    if not points:
        raise PlotError(f"{metrics_path}: no epochs yet")
    return _curve(task_title(task), method, seed, points, str(run_dir))


def load_runs(folder: str | Path) -> list[Curve]:
    """Every run directly under `folder`, by name; folders that are not runs, or have no
    metrics yet, are passed over (a grid's run-dir holds logs and unfinished runs too)."""
    curves = []
    for run_dir in sorted(p for p in Path(folder).iterdir() if p.is_dir()):
        try:
            curves.append(load_run(run_dir))
        except PlotError:
            continue
    return curves


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
    for c in curves:
        key = (c.task, c.method, c.seed)
        kept = by_seed.get(key)
        if kept is not None:
            longer, other = (c, kept) if len(c.epochs) > len(kept.epochs) else (kept, c)
            if notes is not None:
                notes.append(f"{other.source or 'a run'} has the same task, method and seed "
                             f"({c.task}, {c.method}, seed {c.seed}) as {longer.source}: "
                             "counted once, with the longer run")
            c = longer
        by_seed[key] = c
    out: dict[str, dict[str, list[Curve]]] = {}
    for c in by_seed.values():
        out.setdefault(c.task, {}).setdefault(c.method, []).append(c)
    return {t: dict(sorted(ms.items(), key=lambda kv: _method_rank(kv[0])))
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
    """The figure's bands (module docstring). The interval is the percentile interval of
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
    """docs/DESIGN.md §5's numbers for one aggregated method (rule: module docstring)."""
    ma = moving_average(agg.epochs, agg.mean, window)
    crossing: dict[float, int | None] = {}
    for t in thresholds:
        hit = np.nonzero(ma > t + _EPS)[0]
        crossing[t] = int(agg.epochs[hit[0]]) - 1 if len(hit) else None
    lookup = dict(zip(agg.epochs.tolist(), ma.tolist(), strict=True))
    return Milestones(crossing, {e: lookup.get(e) for e in at_epochs}, agg.n_seeds,
                      len(agg.epochs), float(ma[-1]) if len(ma) else None)


def _fmt_rate(v: float | None) -> str:
    if v is None or math.isnan(v):
        return "–"
    text = f"{v:.2f}"
    return text[1:] if text.startswith("0") else text


def markdown_table(task: str, rows: Sequence[tuple[str, Milestones]]) -> str:
    """One task's milestone table; `rows` are (label, milestones)."""
    if not rows:
        return ""
    first = rows[0][1]
    th, at = list(first.crossing), list(first.at)
    head = (["method", "seeds", "epochs"] + [f"epoch at {t:g}" for t in th]
            + [f"success at {e}" for e in at] + ["success at end"])
    lines = [f"### {task}", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    for label, m in rows:
        cells = [label, str(m.n_seeds), str(m.n_epochs)]
        cells += ["–" if m.crossing[t] is None else str(m.crossing[t]) for t in th]
        cells += [_fmt_rate(m.at[e]) for e in at] + [_fmt_rate(m.final)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


TABLE_NOTE = (
    f"Seed mean over the epochs every seed reached, {WINDOW}-epoch trailing moving average. "
    "'epoch at x': first epoch whose average exceeds x, counted from 0 (epochs completed "
    "before it, as in the authors' logs and docs/DESIGN.md §5); 'success at n': the average after "
    "the n-th epoch ('end': the last epoch); '–': never / run too short.\n"
)


def tables(ours: dict[str, dict[str, list[Curve]]],
           reference: dict[str, dict[str, list[Curve]]] | None = None) -> str:
    """Markdown for every task in `ours`, authors' rows beside ours when given."""
    parts = []
    for task, methods in ours.items():
        ref = (reference or {}).get(task, {})
        rows: list[tuple[str, Milestones]] = []
        for method in sorted(set(methods) | set(ref), key=_method_rank):
            label = method_label(method)
            if method in methods:
                rows.append((label + (" (ours)" if reference is not None else ""),
                             milestones(aggregate(methods[method]))))
            if method in ref:
                rows.append((label + " (authors)", milestones(aggregate(ref[method]))))
        parts.append(markdown_table(task, rows))
    return "\n".join(parts) + ("\n" + TABLE_NOTE if parts else "")


def _method_rank(key: str) -> tuple[int, str]:
    """The paper's order; a variant right after its method."""
    method = key.partition("/")[0]
    return (METHOD_ORDER.index(method) if method in METHOD_ORDER else len(METHOD_ORDER), key)


# ---------------------------------------------------------------------------------- figure

def _pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (files only; imported when a figure is drawn)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save_figure(plt: Any, fig: Any, output: str | Path) -> Path:
    if fig.get_layout_engine() is None:
        fig.tight_layout()
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=DPI)
    plt.close(fig)
    return output


def _check_band(band: str) -> None:
    if band not in BANDS:
        raise PlotError(f"band must be one of {', '.join(BANDS)}, got {band!r}")


def _band_rng() -> np.random.Generator:
    """A fresh generator per drawn method, so that its band does not depend on what else
    the figure draws."""
    return np.random.default_rng(CI_SEED)


def _fill_bands(ax: Any, b: Bands, color: str | None, band: str, *, strength: float = 1.0,
                right: float | None = None) -> None:
    """`band` of ci|minmax|both; the min–max lighter than the interval (`strength` scales
    both, for the authors' bands)."""
    keep = b.epochs <= right if right is not None else np.ones(len(b.epochs), dtype=bool)
    if band in ("minmax", "both"):
        ax.fill_between(b.epochs[keep], b.low[keep], b.high[keep], color=color,
                        alpha=(0.10 if band == "both" else 0.18) * strength, linewidth=0)
    if band in ("ci", "both"):
        ax.fill_between(b.epochs[keep], b.ci_low[keep], b.ci_high[keep], color=color,
                        alpha=0.25 * strength, linewidth=0)


_BAND_CAPTIONS: dict[str, str] = {
    "ci": f"the bootstrap {CI_LEVEL * 100:.0f} % interval of their mean (seeds resampled, "
          "a fixed RNG seed)",
    "minmax": "their min–max",
    "both": f"the bootstrap {CI_LEVEL * 100:.0f} % interval of their mean (seeds resampled, "
            "a fixed RNG seed) and, lighter, their min–max",
}


def _band_words(band: str) -> str:
    return {"ci": f"band: {CI_LEVEL * 100:.0f} % CI of the seed mean",
            "minmax": "band: min–max over seeds",
            "both": f"bands: {CI_LEVEL * 100:.0f} % CI of the seed mean,\n"
                    "min–max over seeds (lighter)"}[band]


def _legend_title(keys: set[str], reference: bool, band: str) -> str:
    """What the line styles and bands mean, for the styles drawn."""
    lines = ["solid: ours" + ("; dashed: the authors'" if reference else "")]
    variants = {v for key in keys for v in key.split("/")[1:]}
    styles = [f"{style}: {v}" for v, style in (("lockstep", "dash-dot"), ("bf16", "dotted"))
              if v in variants]
    if styles:
        lines.append("; ".join(styles))
    if "v1" in variants:
        lines.append("(v1): on the authors' Fetch*-v1")
    return "\n".join([*lines, _band_words(band)])


def _seeds(n: int) -> str:
    return f"{n} seed{'s' if n != 1 else ''}"


def plot_figure(ours: dict[str, dict[str, list[Curve]]], output: str | Path,
                reference: dict[str, dict[str, list[Curve]]] | None = None,
                xmax: int | None = None, band: str = DEFAULT_BAND) -> Path:
    """One panel per task, its legend beside it: per method the 10-epoch moving average of
    the seed mean with its bands (`seed_bands`; ours solid, the authors' dashed and smoothed
    alike; the authors' bands only for the methods we ran, the other methods' reference
    means thin). The x axis spans our epochs unless `xmax` is given."""
    from matplotlib.ticker import MaxNLocator

    _check_band(band)
    plt = _pyplot()
    tasks = list(ours)
    fig, axes = plt.subplots(1, len(tasks), figsize=((PANEL_W + LEGEND_W) * len(tasks), PANEL_H),
                             dpi=DPI, squeeze=False, layout="constrained")
    for ax, task in zip(axes[0], tasks, strict=True):
        ref = (reference or {}).get(task, {})
        right = xmax or max(int(c.epochs.max()) for cs in ours[task].values() for c in cs)
        for method in sorted(set(ours[task]) | set(ref), key=_method_rank):
            color = method_color(method)
            label = method_label(method)
            mine = method in ours[task]
            if mine:
                a = aggregate(ours[task][method], every_seed=False)
                _fill_bands(ax, seed_bands(ours[task][method], _band_rng()), color, band)
                ax.plot(a.epochs, moving_average(a.epochs, a.mean), color=color,
                        linestyle=method_linestyle(method), linewidth=2.0, zorder=3,
                        label=f"{label}, {_seeds(a.n_seeds)}")
            if method in ref:
                a = aggregate(ref[method])
                keep = a.epochs <= right
                if mine:  # the authors' band only where it compares to ours
                    _fill_bands(ax, seed_bands(ref[method], _band_rng(), every_seed=True),
                                color, band, strength=0.6, right=right)
                ax.plot(a.epochs[keep], moving_average(a.epochs, a.mean)[keep], "--",
                        color=color, linewidth=1.4 if mine else 1.0,
                        alpha=0.9 if mine else 0.6,
                        label=f"{label}, authors' ({_seeds(a.n_seeds)})")
        ax.set_title(task)
        ax.set_xlabel("epoch")
        ax.set_ylabel(f"success rate ({WINDOW}-epoch mean)")
        ax.set_xlim(1 if right > 1 else 0, right)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # epochs are whole numbers
        ax.set_ylim(-0.01, 1.01)  # curves at exactly 0 or 1 stay visible
        ax.set_yticks(np.linspace(0.0, 1.0, 6))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize=8,
                  frameon=False, title=_legend_title(set(ours[task]), bool(ref), band),
                  title_fontsize=7, alignment="left")
    return _save_figure(plt, fig, output)


# ---------------------------------------------------------------------------------- Fig. 2

FIG2_TASKS: tuple[str, ...] = ("FetchPush", "FetchPickAndPlace", "FetchSlide")
FIG2_ROWS: tuple[tuple[str, str], ...] = (("her", "her-cs"), ("her-ebp", "her-ebp-cs"))
FIG2_EPOCHS = 200


def _panel_title(task: str, pair: tuple[str, str]) -> str:
    return f"{task}: {' vs '.join(method_label(m) for m in pair)}"


def _in_panel(key: str, pair: tuple[str, str]) -> bool:
    """Whether a Fig. 2 panel of `pair` draws method key `key`: the pair's methods, their
    schedule variants (lockstep) and their runs on v1, not the learner's precision variants
    (bf16)."""
    method, *variants = key.split("/")
    return method in pair and "bf16" not in variants


def _has_ours(pair: tuple[str, str], ours: dict[str, list[Curve]]) -> bool:
    """Whether we ran any of the pair's methods (or their variants) on this task."""
    return any(_in_panel(key, pair) for key in ours)


def _fig2_keys(pair: tuple[str, str], ours: dict[str, list[Curve]],
               ref: dict[str, list[Curve]]) -> list[str]:
    """The method keys of one panel, in the paper's order (`_in_panel`)."""
    keys = {k for k in (*ours, *ref) if _in_panel(k, pair)}
    return sorted(keys, key=_method_rank)


def fig2_text(ours: dict[str, dict[str, list[Curve]]],
              reference: dict[str, dict[str, list[Curve]]], band: str = DEFAULT_BAND) -> str:
    """docs/results/fig2.md: one milestone table per panel of the paper's Fig. 2 (`band`:
    what the figure's bands are, for its caption)."""
    parts = [
        "# Fig. 2: ours beside the authors'", "",
        "Drawn by `hercs plot --figure 2` from the committed runs (docs/results/runs/). Rows "
        "of panels: HER vs HER-CS, HER-EBP vs HER-EBP-CS; columns: FetchPush, "
        "FetchPickAndPlace, FetchSlide. Ours solid (lockstep dash-dotted), the authors' "
        f"dashed; both curves are the {WINDOW}-epoch trailing mean of the seed mean (the paper "
        "smooths over 21 epochs and pads short runs; we do neither), and the bands, over the "
        f"seeds' own {WINDOW}-epoch trailing means, are {_BAND_CAPTIONS[band]}. Ours: "
        "gymnasium-robotics Fetch*-v4 on MuJoCo 3, and where labelled (v1) the authors' "
        "environment, gym Fetch*-v1 on mujoco-py, which the authors' curves are on "
        "(docs/DESIGN.md §9.6); (lag 7): asynchronous runs of the old, staler default "
        "(docs/PERFORMANCE.md §2).", "",
    ]
    for pair in FIG2_ROWS:
        for task in FIG2_TASKS:
            mine, ref = ours.get(task, {}), reference.get(task, {})
            title = _panel_title(task, pair)
            rows: list[tuple[str, Milestones]] = []
            for key in _fig2_keys(pair, mine, ref):
                if key in mine:
                    rows.append((method_label(key) + " (ours)", milestones(aggregate(mine[key]))))
                if key in ref:
                    rows.append((method_label(key) + " (authors)",
                                 milestones(aggregate(ref[key]))))
            parts.append(markdown_table(title, rows))
            if not _has_ours(pair, mine):
                parts += ["No runs of ours yet.", ""]
    return "\n".join(parts) + "\n" + TABLE_NOTE


def plot_fig2(ours: dict[str, dict[str, list[Curve]]],
              reference: dict[str, dict[str, list[Curve]]], output: str | Path,
              xmax: int = FIG2_EPOCHS, band: str = DEFAULT_BAND) -> Path:
    """The paper's Fig. 2 layout (2 × 3 panels), rule in `fig2_text`."""
    _check_band(band)
    plt = _pyplot()
    fig, axes = plt.subplots(len(FIG2_ROWS), len(FIG2_TASKS),
                             figsize=(PANEL_W * len(FIG2_TASKS), PANEL_H * len(FIG2_ROWS)),
                             dpi=DPI, squeeze=False)
    for r, pair in enumerate(FIG2_ROWS):
        for c, task in enumerate(FIG2_TASKS):
            ax = axes[r][c]
            mine, ref = ours.get(task, {}), reference.get(task, {})
            for key in _fig2_keys(pair, mine, ref):
                color = method_color(key)
                label = method_label(key)
                if key in ref:
                    a = aggregate(ref[key])
                    _fill_bands(ax, seed_bands(ref[key], _band_rng(), every_seed=True), color,
                                band, strength=0.4)
                    ax.plot(a.epochs, moving_average(a.epochs, a.mean), "--", color=color,
                            linewidth=1.3, label=f"{label} (authors, {_seeds(a.n_seeds)})")
                if key in mine:
                    a = aggregate(mine[key], every_seed=False)
                    _fill_bands(ax, seed_bands(mine[key], _band_rng()), color, band)
                    ax.plot(a.epochs, moving_average(a.epochs, a.mean), color=color,
                            linestyle=method_linestyle(key), linewidth=2.0,
                            label=f"{label} (ours, {_seeds(a.n_seeds)})")
            if not _has_ours(pair, mine):
                ax.text(0.03, 0.95, "no runs of ours yet", transform=ax.transAxes,
                        ha="left", va="top", fontsize=10, color="0.4")
            ax.set_title(_panel_title(task, pair), fontsize=10)
            ax.set_xlim(0, xmax)
            ax.set_ylim(-0.01, 1.01)
            ax.set_xlabel("epoch")
            ax.set_ylabel("success rate")
            ax.grid(True, alpha=0.3)
            ax.legend(loc="lower right", fontsize=7, framealpha=0.9)
    return _save_figure(plt, fig, output)


# ------------------------------------------------------------------------------------- CLI

def distinct_run_dirs(run_dirs: Sequence[str | Path]) -> tuple[list[Path], int]:
    """The run folders in the order given, each once (the shell glob `push-her-*` also
    matches `push-her-cs-*`, so a command line can name a folder twice), and how many
    folders were named more than once."""
    counts = Counter(Path(d).resolve() for d in run_dirs)
    seen: set[Path] = set()
    out = []
    for d in run_dirs:
        key = Path(d).resolve()
        if key not in seen:
            seen.add(key)
            out.append(Path(d))
    return out, sum(1 for n in counts.values() if n > 1)


def run_plot(run_dirs: Sequence[str], output: str, *, reference: bool = False,
             table: str | None = None, reference_csv: str | Path = REFERENCE_CSV,
             xmax: int | None = None, figure: int | None = None,
             band: str = DEFAULT_BAND) -> int:
    """`hercs plot`: the figure at `output`, the tables on stdout (and in `table`);
    `figure=2` draws the paper's Fig. 2 layout (the authors' curves always beside ours).
    A folder named twice is read once, with one line on stderr saying how many were."""
    _check_band(band)
    folders, repeated = distinct_run_dirs(run_dirs)
    notes: list[str] = []
    if repeated:
        notes.append(f"{repeated} run folder{'s' if repeated != 1 else ''} named more than "
                     "once (overlapping globs?): each read once")
    ours = group((load_run(d) for d in folders), notes)
    if figure == 2:
        for note in notes:
            print(f"hercs plot: {note}", file=sys.stderr)
        authors = group(load_reference(reference_csv))
        return _write_outputs(plot_fig2(ours, authors, output, xmax or FIG2_EPOCHS, band),
                              fig2_text(ours, authors, band), table)
    ref = group(load_reference(reference_csv)) if reference else None
    if ref is not None:
        missing = sorted(set(ours) - set(ref))
        if missing:
            notes.append(f"--reference: the authors published no curves for {', '.join(missing)}"
                         f" (they did for {', '.join(sorted(ref))}); drawn without them")
    for note in notes:
        print(f"hercs plot: {note}", file=sys.stderr)
    return _write_outputs(plot_figure(ours, output, ref, xmax, band), tables(ours, ref), table)


def _write_outputs(path: Path, text: str, table: str | None) -> int:
    print(text, end="")
    if table:
        Path(table).write_text(text)
        print(f"wrote {table}")
    print(f"wrote {path}")
    return 0
