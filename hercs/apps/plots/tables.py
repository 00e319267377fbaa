"""The milestone tables of `hercs plot` (`--table`) and docs/results/fig2.md, computed with
hercs/apps/plots/curves.py's rule."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import yaml

from hercs.apps.plots.curves import (
    CI_LEVEL,
    DEFAULT_BAND,
    WINDOW,
    Curve,
    Milestones,
    PlotError,
    aggregate,
    method_label,
    method_rank,
    milestones,
)
from hercs.apps.plots.numbers import power_of_ten, rate
from hercs.apps.plots.series import DEFAULT_CHOICE, DEFAULT_LAG, SeriesChoice, series_list, whose
from hercs.config.algorithm import default_energy_epsilon


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
        cells += [rate(m.at[e]) for e in at] + [rate(m.final)]
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
        for method in sorted(set(methods) | set(ref), key=method_rank):
            label = method_label(method)
            if method in methods:
                rows.append((method_label(method, ours=True)
                             + (" (ours)" if reference is not None else ""),
                             milestones(aggregate(methods[method]))))
            if method in ref:
                rows.append((label + " (authors)", milestones(aggregate(ref[method]))))
        parts.append(markdown_table(task, rows))
    return "\n".join(parts) + ("\n" + TABLE_NOTE if parts else "")


BAND_CAPTIONS: dict[str, str] = {
    "ci": f"the bootstrap {CI_LEVEL * 100:.0f} % interval of their mean (seeds resampled, "
          "a fixed RNG seed)",
    "minmax": "their min–max",
    "both": f"the bootstrap {CI_LEVEL * 100:.0f} % interval of their mean (seeds resampled, "
            "a fixed RNG seed) and, lighter, their min–max",
}


FIG2_LAYOUT = Path(__file__).resolve().parent / "data" / "fig2.yaml"


@dataclass(frozen=True)
class FigureLayout:
    """A paper figure's grid: a row of panels per pair of methods, a column per task, the x
    axis to `epochs`."""

    tasks: tuple[str, ...]
    rows: tuple[tuple[str, str], ...]
    epochs: int


def read_layout(path: Path) -> FigureLayout:
    """The layout a YAML file gives (`tasks`, `rows` of method pairs, `epochs`); PlotError
    naming the file and what is wrong."""
    try:
        data = yaml.safe_load(path.read_text())
        layout = FigureLayout(tuple(str(t) for t in data["tasks"]),
                              tuple((str(a), str(b)) for a, b in data["rows"]),
                              int(data["epochs"]))
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise PlotError(f"{path}: not a figure layout (tasks, rows of method pairs, epochs): "
                        f"{exc!r}") from exc
    return layout


@functools.cache
def fig2_layout() -> FigureLayout:
    """The paper's Fig. 2 (hercs/apps/plots/data/fig2.yaml)."""
    return read_layout(FIG2_LAYOUT)


def in_panel(key: str, pair: tuple[str, str]) -> bool:
    """Whether a Fig. 2 panel of `pair` may draw method key `key`: the pair's methods and
    their variants, not the learner's precision variants (bf16: a speed option, compared in
    docs/PERFORMANCE.md)."""
    method, *variants = key.split("/")
    return method in pair and "bf16" not in variants


@dataclass(frozen=True)
class Panel:
    """One panel of Fig. 2: our series it draws and leaves out (`SeriesChoice`), and the
    authors' curves beside them."""

    task: str
    pair: tuple[str, str]
    drawn: list[str]
    left: list[str]
    authors: list[str]

    @property
    def title(self) -> str:
        return f"{self.task}: {' vs '.join(method_label(m) for m in self.pair)}"


def fig2_panels(ours: dict[str, dict[str, list[Curve]]],
                reference: dict[str, dict[str, list[Curve]]],
                choice: SeriesChoice = DEFAULT_CHOICE) -> list[Panel]:
    """The 2 × 3 panels, row by row. The authors' curves of both methods are drawn (the
    paper's figure), or with `--series` those of the methods drawn; by default our series
    fill what they leave of `choice.limit`."""
    panels = []
    layout = fig2_layout()
    for pair in layout.rows:
        for task in layout.tasks:
            mine, ref = ours.get(task, {}), reference.get(task, {})
            authors = [m for m in pair if m in ref]
            limit = replace(choice, limit=max(0, choice.limit - len(authors)))
            drawn, left = limit.choose((k for k in mine if in_panel(k, pair)),
                                       lambda _key, _drawn: 1)
            if choice.patterns:
                authors = [m for m in authors if any(k.split("/")[0] == m for k in drawn)]
            panels.append(Panel(task, pair, drawn, left, authors))
    return panels


def _caption_notes(keys: set[str]) -> str:
    """What the labels of `keys` need said, each only where such a series is drawn."""
    eps_v4, eps_v1 = (power_of_ten(default_energy_epsilon(v)) for v in ("v4", "v1"))
    notes = [f"ε: EBP's energy floor `energy.epsilon` (the default {eps_v4} on v4, {eps_v1} "
             "on v1), said for an energy-prioritised series but where it is v1's default"]
    if any("lag=" in k for k in keys):
        notes.append("lag bound, prefetch, actor queue, rate tolerance: an asynchronous run's "
                     "policy-lag settings `training.max_policy_lag`, `learner.prefetch_depth`, "
                     "`actor.insert_queue`, `replay.rate_tolerance_updates`, said where they "
                     f"are not the defaults ({DEFAULT_LAG.bound}, {DEFAULT_LAG.prefetch}, "
                     f"{DEFAULT_LAG.queue}, {DEFAULT_LAG.tolerance:g}; docs/PERFORMANCE.md §2)")
    notes += [f"({whose(k)}): runs made by the {whose(k)}, not by hercs"
              for k in sorted(keys) if whose(k) != "ours"]
    return "".join(f"; {n}" for n in dict.fromkeys(notes))


def fig2_text(ours: dict[str, dict[str, list[Curve]]],
              reference: dict[str, dict[str, list[Curve]]], band: str = DEFAULT_BAND,
              choice: SeriesChoice = DEFAULT_CHOICE) -> str:
    """docs/results/fig2.md: one milestone table per panel of the paper's Fig. 2, every
    series of ours in it and the authors' curves of the panel's methods, then the series
    the figure leaves out (`band`: what the figure's bands are, for its caption)."""
    panels = fig2_panels(ours, reference, choice)
    keys = {k for p in panels for k in (*p.drawn, *p.left)}
    layout = fig2_layout()
    pairs = ", ".join(" vs ".join(method_label(m) for m in pair) for pair in layout.rows)
    parts = [
        "# Fig. 2: ours beside the authors'", "",
        "Drawn by `hercs plot --figure 2` from the run folders given. Rows "
        f"of panels: {pairs}; columns: {', '.join(layout.tasks)}. "
        "A method has one colour; the authors' curves are "
        "dashed, with hollow squares; ours are solid where a series has hercs' defaults, in "
        "another line style where its label names a changed setting, with circles on our "
        "default simulator and squares on the authors' (docs/results/README.md, Glossary). "
        f"Both curves are the {WINDOW}-epoch trailing mean of the seed mean (the paper "
        "smooths over 21 epochs and pads short runs; we do neither), and the bands, over the "
        f"seeds' own {WINDOW}-epoch trailing means, are {BAND_CAPTIONS[band]}. Ours: "
        "gymnasium-robotics Fetch*-v4 on MuJoCo 3, and where labelled \"authors' simulator "
        "(v1)\" the authors' environment, gym Fetch*-v1 on mujoco-py, which the authors' "
        "curves are on "
        f"(docs/DESIGN.md §9.6){_caption_notes(keys)}. A panel draws at most "
        f"{choice.limit} series, the authors' two and ours with the fewest settings changed "
        "from hercs' defaults (those on v1 next); each table lists every series, and under "
        "it those the figure leaves out (`hercs plot --all-series` or `--series PATTERN` "
        "draws them).", "",
    ]
    for panel in panels:
        mine, ref = ours.get(panel.task, {}), reference.get(panel.task, {})
        rows: list[tuple[str, Milestones]] = []
        for key in sorted({*panel.drawn, *panel.left, *panel.authors}, key=method_rank):
            label = method_label(key)
            if key in mine:
                rows.append((f"{method_label(key, ours=True)} ({whose(key)})",
                             milestones(aggregate(mine[key]))))
            if key in panel.authors:
                rows.append((label + " (authors)", milestones(aggregate(ref[key]))))
        parts.append(markdown_table(panel.title, rows))
        if not panel.drawn and not panel.left:
            parts += ["No runs of ours yet.", ""]
        elif panel.left:
            parts += [f"Not drawn: {series_list(panel.left)}.", ""]
    return "\n".join(parts) + "\n" + TABLE_NOTE
