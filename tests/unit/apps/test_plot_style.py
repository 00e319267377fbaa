"""The style contract of every figure hercs draws (hercs/apps/plots/style.py): each series of a
figure has its own (colour, line style), a method one colour everywhere; labels say a run's
settings in words, never the key's tokens; two curves that coincide both stay visible."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hercs.apps.plots import command as plot_command
from hercs.apps.plots import curves as plots
from hercs.apps.plots.series import SeriesChoice, series_label
from hercs.apps.plots.style import (
    METHOD_COLORS,
    PUBLISHED,
    Line,
    assign_styles,
    mark_every,
)
from hercs.apps.sweep import cells as sc
from hercs.apps.sweep import report as sr
from studies.run_curves import load_runs
from tests.support import REPO
from tests.unit.apps.plot_runs import line_look
from tests.unit.apps.sweep_runs import finished_run

RUNS = REPO / "docs" / "results" / "runs"
INTERNAL = re.compile(r"eps\d|lag=|share=|∞|/|\bts\d|authors-code|\d+e-\d+|\(lag ")
"""What a series key says that a label must say in words instead."""


def _committed_keys() -> set[str]:
    return {k for methods in plots.group(load_runs(RUNS)).values() for k in methods}


def test_every_committed_series_and_the_authors_curves_have_distinct_colour_and_line_style(
) -> None:
    """All of them in one figure, as `hercs plot --all-series docs/results/runs/*/ --reference`
    would draw them: no two share (colour, line style), each method keeps its colour and the
    authors' published curves alone are dashed."""
    keys = _committed_keys()
    assert len(keys) >= 20  # the committed grid's series: the check has something to check
    lines = [*(Line(k) for k in keys), *(Line(m, published=True) for m in METHOD_COLORS)]
    styles = assign_styles(lines)
    pairs = [(s.color, s.dash) for s in styles.values()]
    assert len(set(pairs)) == len(pairs) == len(lines)
    for line, style in styles.items():
        assert style.color == METHOD_COLORS[line.key.split("/")[0]]
        assert (style.dash == PUBLISHED) == line.published
    # the same lines, the same styles, in whatever order they come
    assert assign_styles(reversed(lines)) == styles


def test_labels_say_settings_in_words_not_the_keys_tokens() -> None:
    labels = {k: series_label(k) for k in _committed_keys()}
    assert all(not INTERNAL.search(label) for label in labels.values()), {
        k: v for k, v in labels.items() if INTERNAL.search(v)}
    assert labels["her-cs/lockstep"] == "HER-CS, lockstep (as the authors' code)"
    assert labels["her-ebp/eps0.001"] == "HER-EBP, ε = 10⁻³"
    assert labels["her-ebp"] == "HER-EBP, ε = 10⁻⁶"  # a v4 run of the old default says so
    assert labels["her-cs/v1"] == "HER-CS, authors' simulator (v1)"
    assert labels["her-cs/lag=80,3,2,-1"] == (
        "HER-CS, no lag bound, prefetch 3, actor queue 2, rate tolerance 80")
    # and so do the committed Fig. 2 tables, every row's label
    rows = [line.split("|")[1] for line in
            (REPO / "docs" / "results" / "fig2.md").read_text().splitlines()
            if line.startswith("| ") and not line.startswith("| method")]
    assert rows and not [r for r in rows if INTERNAL.search(r)]


def test_every_line_drawn_in_figure_2_has_its_own_look(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The committed runs' Fig. 2, every series drawn: read back from the figure itself, no
    two lines of a panel share (colour, line style), nor two of the figure a look."""
    import matplotlib.pyplot as plt

    figures: list[Any] = []
    monkeypatch.setattr(plt, "close", figures.append)
    runs = sorted(str(p) for p in RUNS.iterdir() if p.is_dir())
    assert plot_command.run_plot(runs, str(tmp_path / "fig2.png"), figure=2,
                                 choice=SeriesChoice(every=True)) == 0
    [fig] = figures
    panels = [[line_look(line) for line in ax.lines] for ax in fig.axes]
    assert sum(map(len, panels)) >= 30
    for looks in panels:
        pairs = [look[:2] for look in looks]
        assert len(set(pairs)) == len(pairs), looks
    labels = [line.get_label() for ax in fig.axes for line in ax.lines]
    assert not [x for x in labels if INTERNAL.search(x)]


def test_markers_of_a_panels_lines_never_fall_on_one_epoch() -> None:
    """Where a panel has at least as many epochs as lines; every line shows a marker."""
    for slots in (1, 2, 3, 6, 9):
        for span, points in ((4, 4), (12, 12), (50, 50), (200, 200)):
            marked = [set(range(*_start_step(mark_every(points, span, s, slots), points)))
                      for s in range(slots)]
            assert all(marked), (slots, span)  # every line shows at least one marker
            if points >= slots:  # else some must share: as few as can
                assert sum(map(len, marked)) == len(set().union(*marked)), (slots, span)


def _start_step(every: tuple[int, int], points: int) -> tuple[int, int, int]:
    return every[0], points, every[1]


def _pixels_near(image: np.ndarray, color: str, tol: int = 32) -> int:
    """Pixels of `image` (RGB, 0–255) within `tol` of `color`: a line drawn at alpha 0.9
    lies within 26 of it on white and within 22 on another line; a band (alpha .25) far off."""
    rgb = np.array([int(color[i:i + 2], 16) for i in (1, 3, 5)], dtype=float)
    target = rgb
    return int((np.abs(image - target).max(axis=-1) <= tol).sum())


def test_a_sweep_report_shows_both_of_two_identical_curves(tmp_path: Path) -> None:
    """HER and HER-CS both at .99 from the second epoch: the report's figure (plot_figure)
    still shows each method's colour inside the axes, not only in the legend: the later line
    covers the earlier, but their markers fall on other epochs."""
    import matplotlib.image as mpimg

    success = [0.2] + [0.99] * 29
    cells = [sc.GridRun("push", "her", 1), sc.GridRun("push", "her-cs", 1)]
    for cell in cells:
        finished_run(tmp_path / "runs", cell, success)
    sr.write_reports(cells, tmp_path / "runs", tmp_path / "out", command="x", reps=200)
    image = mpimg.imread(tmp_path / "out" / "push.png")[..., :3] * 255.0
    width = image.shape[1]
    # the panel is the left PANEL_W of each (PANEL_W + LEGEND_W): legend entries lie right
    axes_part = image[:, : int(width * 0.9 * plots.PANEL_W / (plots.PANEL_W + plots.LEGEND_W))]
    her, cs = (_pixels_near(axes_part, METHOD_COLORS[m]) for m in ("her", "her-cs"))
    assert her > 100 and cs > 100, (her, cs)
    # the same two curves with one look each would leave only the top one's colour: the
    # markers are what keeps HER visible (a check that the measure can fail)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(plots.PANEL_W, plots.PANEL_H), dpi=plots.DPI)
    epochs = np.arange(1, len(success) + 1)
    for method in ("her", "her-cs"):
        ax.plot(epochs, success, color=METHOD_COLORS[method], linewidth=2.0, alpha=0.9)
    ax.set_ylim(-0.01, 1.01)
    fig.savefig(tmp_path / "plain.png", dpi=plots.DPI)
    plt.close(fig)
    plain = mpimg.imread(tmp_path / "plain.png")[..., :3] * 255.0
    assert _pixels_near(plain, METHOD_COLORS["her"]) < 10 < _pixels_near(
        plain, METHOD_COLORS["her-cs"])
