"""`hercs plot`: loading run folders, seed aggregation, the milestone table (pinned by hand and
against docs/DESIGN.md §5 from the authors' CSV), the figure file. Seed bands, groups,
variants, the CLI and legends: test_plots_groups.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hercs.apps.plots import curves as plots
from hercs.apps.plots import figures as plot_figures
from hercs.apps.plots import tables as plot_tables
from tests.unit.apps.plot_runs import CURVES, _write_run


def test_load_run_reads_config_and_metrics(run_dirs: list[Path]) -> None:
    c = plots.load_run(run_dirs[0])
    assert (c.task, c.method, c.seed) == ("FetchPush", "her", 1)
    assert c.epochs.tolist() == list(range(1, 16))
    assert c.success.tolist() == CURVES[("her", 1)]


def test_aggregation_mean_min_max_over_common_epochs(run_dirs: list[Path]) -> None:
    groups = plots.group(plots.load_run(d) for d in run_dirs)
    assert list(groups) == ["FetchPush"]
    assert list(groups["FetchPush"]) == ["her", "her-cs"]
    her = plots.aggregate(groups["FetchPush"]["her"])
    assert her.n_seeds == 2
    assert her.epochs.tolist() == list(range(1, 16))
    assert her.mean.tolist() == [0, 0, 0, 0, 0.5, 0.5] + [1.0] * 9
    assert her.low.tolist() == [0.0] * 6 + [1.0] * 9
    assert her.high.tolist() == [0.0] * 4 + [1.0] * 11
    cs = plots.aggregate(groups["FetchPush"]["her-cs"])
    assert cs.epochs.tolist() == [1, 2, 3, 4, 5, 6]  # seed 2 stopped at 6
    assert cs.mean == pytest.approx([0.0, 0.1, 0.3, 0.5, 0.7, 0.9])
    assert cs.low == pytest.approx([0.0, 0.0, 0.2, 0.4, 0.6, 0.8])
    assert cs.high == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])


def test_moving_average_is_trailing_over_available_epochs() -> None:
    mean = np.array([0, 0, 0, 0, 0.5, 0.5] + [1.0] * 9)
    ma = plots.moving_average(np.arange(1, 16), mean)
    # epoch e: mean of epochs max(1, e-9)..e
    expected = [0, 0, 0, 0, 0.5 / 5, 1 / 6, 2 / 7, 3 / 8, 4 / 9, 5 / 10,
                6 / 10, 7 / 10, 8 / 10, 9 / 10, 9.5 / 10]
    assert ma == pytest.approx(expected)


def test_milestones_by_hand(run_dirs: list[Path]) -> None:
    groups = plots.group(plots.load_run(d) for d in run_dirs)["FetchPush"]
    her = plots.milestones(plots.aggregate(groups["her"]), at_epochs=(5, 10, 15, 50))
    # MA = 0.5 exactly at epoch 10 (a tie does not count), 0.6 at 11 -> "epoch at 0.5" = 10
    # (epochs completed before the first epoch that exceeds it); MA 0.9 at 14, 0.95 at 15 -> 14.
    assert her.crossing == {0.5: 10, 0.9: 14}
    assert her.at[5] == pytest.approx(0.1)
    assert her.at[10] == pytest.approx(0.5)
    assert her.at[15] == pytest.approx(0.95)
    assert her.at[50] is None
    assert (her.n_seeds, her.n_epochs) == (2, 15)
    assert her.final == pytest.approx(0.95)
    cs = plots.milestones(plots.aggregate(groups["her-cs"]))
    assert cs.crossing == {0.5: None, 0.9: None}
    assert cs.at == {50: None, 100: None, 200: None}
    assert cs.final == pytest.approx(2.5 / 6)


def test_table_text_by_hand(run_dirs: list[Path]) -> None:
    text = plot_tables.tables(plots.group(plots.load_run(d) for d in run_dirs))
    assert "### FetchPush" in text
    assert "| HER | 2 | 15 | 10 | 14 | – | – | – | .95 |" in text
    assert "| HER-CS | 2 | 6 | – | – | – | – | – | .42 |" in text


# docs/DESIGN.md §5, row by row: (epoch at 0.5, epoch at 0.9, success at 50, 100, 200).
DESIGN_5 = {
    ("FetchPush", "her"): (55, 95, .41, .90, .99),
    ("FetchPush", "her-cs"): (43, 61, .70, .98, None),
    ("FetchPush", "her-ebp"): (23, 34, .97, 1.0, None),
    ("FetchPush", "her-ebp-cs"): (22, 31, .99, .99, None),
    ("FetchPickAndPlace", "her"): (62, 186, .39, .71, .89),
    ("FetchPickAndPlace", "her-cs"): (59, 94, .40, .93, .95),
    ("FetchPickAndPlace", "her-ebp"): (44, 97, .58, .90, .93),
    ("FetchPickAndPlace", "her-ebp-cs"): (40, 71, .67, .96, .95),
    ("FetchSlide", "her"): (127, None, .36, .47, .56),
    ("FetchSlide", "her-cs"): (92, None, .38, .51, .57),
}


def test_authors_csv_reproduces_design_section_5() -> None:
    ref = plots.group(plots.load_reference(plots.REFERENCE_CSV))
    assert set(ref) == {"FetchPush", "FetchPickAndPlace", "FetchSlide"}
    for (task, method), (e5, e9, s50, s100, s200) in DESIGN_5.items():
        m = plots.milestones(plots.aggregate(ref[task][method]))
        got = (m.crossing[0.5], m.crossing[0.9],
               *(None if m.at[e] is None else round(m.at[e], 2) for e in (50, 100, 200)))
        assert got == (e5, e9, s50, s100, s200), (task, method)
        assert m.n_seeds == 5
    # The table cells as printed (ties like .985 -> ".98" as DESIGN has them).
    # the methods' names, not labelled as runs of ours
    text = "".join(plot_tables.markdown_table(task, [
        (plots.method_label(m), plots.milestones(plots.aggregate(cs)))
        for m, cs in methods.items()]) for task, methods in ref.items())
    assert "| HER | 5 | 200 | 55 | 95 | .41 | .90 | .99 |" in text
    assert "| HER-CS | 5 | 125 | 43 | 61 | .70 | .98 | – |" in text  # one seed stops at 125
    assert "| HER-EBP | 5 | 100 | 23 | 34 | .97 | 1.00 | – |" in text
    assert "| HER-EBP-CS | 5 | 200 | 40 | 71 | .67 | .96 | .95 |" in text


def test_design_rule_details_pinned() -> None:
    """Why the rule is 'first epoch that exceeds, counted from 0': Push HER's moving average is
    exactly 0.5 at its 55th epoch and §5 says 55; counting from 1 would give 56 and 96."""
    ref = plots.group(plots.load_reference(plots.REFERENCE_CSV))
    agg = plots.aggregate(ref["FetchPush"]["her"])
    ma = plots.moving_average(agg.epochs, agg.mean)
    assert ma[54] == pytest.approx(0.5) and ma[53] < 0.5 and ma[55] > 0.5
    first_over_09 = int(agg.epochs[np.nonzero(ma > 0.9)[0][0]])
    assert first_over_09 == 96  # reported as 95
    # Seeds are cut to their common epochs: with the mean over the seeds available at each
    # epoch Push HER-CS would have a value at 200, but §5 has "–".
    assert plots.aggregate(ref["FetchPush"]["her-cs"]).epochs[-1] == 125


def test_the_authors_runs_are_one_workers_twenty_test_episodes() -> None:
    """Their train.py averages the test success over MPI workers, each testing 20 episodes
    (`--n-test-rollouts 20`), so with k workers a value is a multiple of 1/(20k), and with
    k >= 2 half of them or more fall between multiples of 1/20. Every published value is on the
    1/20 grid: their runs had one worker, as the peer baseline does (docs/reference/README.md)."""
    values = np.concatenate([c.success for c in plots.load_reference(plots.REFERENCE_CSV)])
    assert values.size > 10_000
    assert np.all(np.abs(values * 20 - np.round(values * 20)) < 1e-9)


def test_figure_is_a_non_blank_png_of_the_expected_size(run_dirs: list[Path],
                                                        tmp_path: Path) -> None:
    import matplotlib.image as mpimg

    ours = plots.group(plots.load_run(d) for d in run_dirs)
    ours.update(plots.group([plots.load_run(_write_run(tmp_path, "her", 3, [0.1, 0.3],
                                                       task="slide"))]))
    out = plot_figures.plot_figure(ours, tmp_path / "fig.png",
                            plots.group(plots.load_reference(plots.REFERENCE_CSV)))
    img = mpimg.imread(out)
    h, w = round(plots.PANEL_H * plots.DPI), round((plots.PANEL_W + plots.LEGEND_W) * plots.DPI)
    assert img.shape == (h, 2 * w, 4)  # two panels, each with its legend beside it
    assert img[..., :3].var() > 1e-3


def test_the_legend_sits_beside_the_axes_not_over_them(run_dirs: list[Path],
                                                       tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A dozen entries over the curves was the README example's figure: every legend's box
    lies right of its axes' box, inside the figure."""
    import matplotlib.pyplot as plt

    figures = []
    monkeypatch.setattr(plt, "close", figures.append)  # keep the figure to look at it
    ours = plots.group(plots.load_run(d) for d in run_dirs)
    plot_figures.plot_figure(ours, tmp_path / "fig.png",
                      plots.group(plots.load_reference(plots.REFERENCE_CSV)))
    [fig] = figures
    renderer = fig.canvas.get_renderer()
    [ax] = fig.axes
    axes_box = ax.get_window_extent(renderer)
    legend_box = ax.get_legend().get_window_extent(renderer)
    assert legend_box.x0 > axes_box.x1
    assert legend_box.x1 <= fig.bbox.x1 and legend_box.y0 >= fig.bbox.y0
    title = ax.get_legend().get_title().get_text()
    assert title.startswith("colour: the method; solid: ours, hercs' defaults\n"
                            "dashed: the authors' published")
    assert "other lines" not in title  # no changed setting drawn, no style to explain
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[:2] == ["HER, 2 seeds", "HER, authors' published (5 seeds)"]
    plt.close(fig)
