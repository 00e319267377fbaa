"""`hercs plot`'s drawing: the learning-curve figures, one panel per task or the paper's
Fig. 2 (plot_command.py chooses what they draw and writes them with their tables)."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import numpy as np

from hercs.apps.plots.curves import (
    BANDS,
    CI_LEVEL,
    CI_SEED,
    DEFAULT_BAND,
    DPI,
    LEGEND_W,
    PANEL_H,
    PANEL_W,
    WINDOW,
    Bands,
    Curve,
    PlotError,
    aggregate,
    method_label,
    method_rank,
    moving_average,
    seed_bands,
)
from hercs.apps.plots.series import series_label, whose
from hercs.apps.plots.style import Line, LineStyle, assign_styles, legend_key, mark_every
from hercs.apps.plots.tables import (
    Panel,
    fig2_layout,
    fig2_panels,
)

LEGEND_WRAP = 40  # characters a legend line beside a panel holds at its font size
FIG2_WRAP = 44  # and one inside a Fig. 2 panel


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


def check_band(band: str) -> None:
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




def _band_words(band: str) -> str:
    return {"ci": f"band: {CI_LEVEL * 100:.0f} % CI of the seed mean",
            "minmax": "band: min–max over seeds",
            "both": f"bands: {CI_LEVEL * 100:.0f} % CI of the seed mean,\n"
                    "min–max over seeds (lighter)"}[band]


def _seeds(n: int) -> str:
    return f"{n} seed{'s' if n != 1 else ''}"


def _draw(ax: Any, epochs: np.ndarray, values: np.ndarray, style: LineStyle, label: str, *,
          span: int, slots: int, wrap: int) -> None:
    """One series in its style (style.py): the authors' thinner with hollow markers, ours
    above them; each line a little above the one before, and its markers staggered against
    the panel's `slots` lines (`mark_every`), so that a line that coincides with another
    still shows."""
    slot = len(ax.lines)  # the lines drawn here before this one
    ax.plot(epochs, values, color=style.color, linestyle=style.dash.pattern,
            linewidth=1.4 if style.hollow else 2.0, alpha=0.9, marker=style.marker.symbol,
            markevery=mark_every(len(epochs), span, slot, slots),
            markersize=4.0 if style.hollow else 4.5, markeredgewidth=1.0,
            markerfacecolor="white" if style.hollow else style.color,
            markeredgecolor=style.color, zorder=(2.5 if style.hollow else 3.0) + 0.01 * slot,
            label=textwrap.fill(label, wrap, break_on_hyphens=False))


def plot_figure(ours: dict[str, dict[str, list[Curve]]], output: str | Path,
                reference: dict[str, dict[str, list[Curve]]] | None = None,
                xmax: int | None = None, band: str = DEFAULT_BAND) -> Path:
    """One panel per task, its legend beside it: per series of `ours` the 10-epoch moving
    average of the seed mean with its bands (`seed_bands`), and the authors' smoothed alike,
    for the methods of `reference` given (`run_plot` passes those of the series drawn),
    each in its style (`assign_styles`, one for the whole figure). The x axis spans our
    epochs unless `xmax` is given."""
    from matplotlib.ticker import MaxNLocator

    check_band(band)
    plt = _pyplot()
    tasks = list(ours)
    styles = assign_styles([*(Line(k) for methods in ours.values() for k in methods),
                            *(Line(k, published=True) for methods in (reference or {}).values()
                              for k in methods)])
    fig, axes = plt.subplots(1, len(tasks), figsize=((PANEL_W + LEGEND_W) * len(tasks), PANEL_H),
                             dpi=DPI, squeeze=False, layout="constrained")
    for ax, task in zip(axes[0], tasks, strict=True):
        ref = (reference or {}).get(task, {})
        right = xmax or max(int(c.epochs.max()) for cs in ours[task].values() for c in cs)
        drawn = []
        slots = len(ours[task]) + len(ref)
        for method in sorted(set(ours[task]) | set(ref), key=method_rank):
            if method in ours[task]:
                style = styles[Line(method)]
                a = aggregate(ours[task][method], every_seed=False)
                _fill_bands(ax, seed_bands(ours[task][method], _band_rng()), style.color, band)
                _draw(ax, a.epochs, moving_average(a.epochs, a.mean), style,
                      f"{series_label(method)}, {_seeds(a.n_seeds)}", span=right,
                      slots=slots, wrap=LEGEND_WRAP)
                drawn.append(style)
            if method in ref:
                style = styles[Line(method, published=True)]
                a = aggregate(ref[method])
                keep = a.epochs <= right
                _fill_bands(ax, seed_bands(ref[method], _band_rng(), every_seed=True),
                            style.color, band, strength=0.6, right=right)
                _draw(ax, a.epochs[keep], moving_average(a.epochs, a.mean)[keep], style,
                      f"{method_label(method)}, authors' published ({_seeds(a.n_seeds)})",
                      span=right, slots=slots, wrap=LEGEND_WRAP)
                drawn.append(style)
        ax.set_title(task)
        ax.set_xlabel("epoch")
        ax.set_ylabel(f"success rate ({WINDOW}-epoch mean)")
        ax.set_xlim(1 if right > 1 else 0, right)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # epochs are whole numbers
        ax.set_ylim(-0.01, 1.01)  # curves at exactly 0 or 1 stay visible
        ax.set_yticks(np.linspace(0.0, 1.0, 6))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize=8,
                  frameon=False, title=f"{legend_key(drawn)}\n{_band_words(band)}",
                  title_fontsize=7, alignment="left")
    _fit_legends(fig, [ax.get_legend() for ax in axes[0]])
    return _save_figure(plt, fig, output)


def _fit_legends(fig: Any, legends: list[Any], margin_px: float = 4.0) -> None:
    """Grow the figure until every legend lies inside it: a legend of many groups would
    otherwise run off the image's bottom edge (the panels grow with it)."""
    for _ in range(4):  # constrained layout moves the axes as the figure grows
        fig.canvas.draw()
        lowest = min(legend.get_window_extent().y0 for legend in legends)
        if lowest >= margin_px:
            return
        fig.set_figheight(fig.get_figheight() + (margin_px - lowest) / fig.dpi + 0.1)


def plot_fig2(ours: dict[str, dict[str, list[Curve]]],
              reference: dict[str, dict[str, list[Curve]]], output: str | Path,
              xmax: int | None = None, band: str = DEFAULT_BAND,
              panels: list[Panel] | None = None) -> Path:
    """The paper's Fig. 2 layout (`fig2_layout`'s rows × tasks panels, `fig2_panels`; rule in
    `fig2_text`; the x axis to its epochs unless `xmax`), every line in its style
    (`assign_styles`, one for the whole figure)."""
    check_band(band)
    layout = fig2_layout()
    xmax = layout.epochs if xmax is None else xmax
    panels = panels if panels is not None else fig2_panels(ours, reference)
    plt = _pyplot()
    rows, columns = len(layout.rows), len(layout.tasks)
    fig, axes = plt.subplots(rows, columns, figsize=(PANEL_W * columns, PANEL_H * rows),
                             dpi=DPI, squeeze=False)
    styles = assign_styles([*(Line(k) for p in panels for k in p.drawn),
                            *(Line(k, published=True) for p in panels for k in p.authors)])
    for i, panel in enumerate(panels):
        r, c = divmod(i, columns)
        ax = axes[r][c]
        mine, ref = ours.get(panel.task, {}), reference.get(panel.task, {})
        slots = len(panel.drawn) + len(panel.authors)
        for key in sorted({*panel.drawn, *panel.authors}, key=method_rank):
            if key in panel.authors:
                style = styles[Line(key, published=True)]
                a = aggregate(ref[key])
                _fill_bands(ax, seed_bands(ref[key], _band_rng(), every_seed=True), style.color,
                            band, strength=0.4)
                _draw(ax, a.epochs, moving_average(a.epochs, a.mean), style,
                      f"{method_label(key)} (authors' published, {_seeds(a.n_seeds)})",
                      span=xmax, slots=slots, wrap=FIG2_WRAP)
            if key in panel.drawn:
                style = styles[Line(key)]
                a = aggregate(mine[key], every_seed=False)
                _fill_bands(ax, seed_bands(mine[key], _band_rng()), style.color, band)
                _draw(ax, a.epochs, moving_average(a.epochs, a.mean), style,
                      f"{method_label(key, ours=True)} ({whose(key)}, {_seeds(a.n_seeds)})",
                      span=xmax, slots=slots, wrap=FIG2_WRAP)
        if not panel.drawn and not panel.left:
            ax.text(0.03, 0.95, "no runs of ours yet", transform=ax.transAxes,
                    ha="left", va="top", fontsize=10, color="0.4")
        ax.set_title(panel.title, fontsize=10)
        ax.set_xlim(0, xmax)
        ax.set_ylim(-0.01, 1.01)
        ax.set_xlabel("epoch")
        ax.set_ylabel("success rate")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right", fontsize=6.5, framealpha=0.9)
    return _save_figure(plt, fig, output)
