"""`hercs plot`: seed bands, looks that tell series apart (the contract: test_plot_style.py),
variants as methods of their own, Figure 2, the CLI and legends that fit."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hercs.apps.cli.main import main
from hercs.apps.plots import command as plot_command
from hercs.apps.plots import curves as plots
from hercs.apps.plots import tables as plot_tables
from hercs.apps.plots.series import MAX_SERIES, SeriesChoice
from hercs.rl.methods import METHODS
from hercs.run.rundir import RunDir
from tests.unit.apps.plot_runs import (
    CURVES,
    _write_lockstep_run,
    _write_run,
    _write_variant_run,
    line_look,
)

REPO = Path(__file__).resolve().parents[3]


def _constant(seed: int, value: float, n: int = 12) -> plots.Curve:
    return plots.Curve("FetchPush", "her", seed, np.arange(1, n + 1), np.full(n, value))


def test_seed_bands_by_hand() -> None:
    """Four seeds flat at 0, 0, 0, 1: their moving averages are the same constants. The
    seed mean is .25; resampled means are k/4 for k ones drawn, P(k ≥ 3) = 5.1 % and
    P(k = 4) = 0.4 %, so the 97.5th percentile is .75, and P(k = 0) = 32 % puts the 2.5th at
    0. Min–max: 0 and 1."""
    curves = [_constant(s, v) for s, v in enumerate([0.0, 0.0, 0.0, 1.0], start=1)]
    b = plots.seed_bands(curves, np.random.default_rng(0))
    assert b.n_seeds == 4 and b.epochs.tolist() == list(range(1, 13))
    assert b.mean == pytest.approx([0.25] * 12)
    assert b.ci_low.tolist() == [0.0] * 12 and b.ci_high.tolist() == [0.75] * 12
    assert b.low.tolist() == [0.0] * 12 and b.high.tolist() == [1.0] * 12
    again = plots.seed_bands(curves, np.random.default_rng(0))
    assert np.array_equal(again.ci_high, b.ci_high)  # a fixed seed, a fixed band


def test_seed_bands_are_over_the_seeds_own_moving_averages_to_each_runs_end() -> None:
    """A 0→1 step: the bands follow the trailing mean, not the raw step; past the short
    seed's end the one seed left is its own band."""
    step = plots.Curve("FetchPush", "her", 1, np.arange(1, 11), np.array([0.0] * 5 + [1.0] * 5))
    short = plots.Curve("FetchPush", "her", 2, np.arange(1, 6), np.zeros(5))
    b = plots.seed_bands([step, short], np.random.default_rng(0))
    assert b.epochs.tolist() == list(range(1, 11))
    smoothed = plots.moving_average(step.epochs, step.success)  # 0 ×5, then 1/6 … 5/10
    assert b.high[5:] == pytest.approx(smoothed[5:])
    assert b.ci_low[5:] == pytest.approx(smoothed[5:])  # one seed: no spread to resample
    assert b.ci_high[5:] == pytest.approx(smoothed[5:])
    assert b.mean[:5].tolist() == [0.0] * 5
    with pytest.raises(ValueError):
        plots.seed_bands([], np.random.default_rng(0))


def test_run_dir_without_metrics_names_it(tmp_path: Path, capsys) -> None:
    run = _write_run(tmp_path, "her", 1, [0.0])
    RunDir(run).metrics.unlink()
    with pytest.raises(plots.PlotError, match=rf"{run}.*metrics\.csv"):
        plots.load_run(run)
    assert main(["plot", str(run), "-o", str(tmp_path / "f.png")]) == 2  # a bad path
    err = capsys.readouterr().err
    assert str(run) in err and "metrics.csv" in err


def test_cli_plot_writes_figure_and_table(run_dirs: list[Path], tmp_path: Path,
                                          capsys) -> None:
    out, table = tmp_path / "out" / "fig.png", tmp_path / "table.md"
    argv = ["plot", *map(str, run_dirs), "-o", str(out), "--reference", "--table", str(table)]
    assert main(argv) == 0
    assert out.is_file() and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "| HER (ours) | 2 | 15 | 10 | 14 |" in printed
    assert "| HER (authors) | 5 | 200 | 55 | 95 |" in printed
    assert table.read_text() in printed


def test_runs_of_one_seed_count_once_and_each_run_is_drawn_to_its_end(tmp_path: Path,
                                                                      capsys) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    short = plots.load_run(_write_run(tmp_path / "a", "her", 1, [0.1, 0.2]))
    long = plots.load_run(_write_run(tmp_path / "b", "her", 1, [0.1, 0.2, 0.3, 0.4]))
    other = plots.load_run(_write_run(tmp_path, "her", 2, [0.5, 0.6, 0.7]))
    notes: list[str] = []
    groups = plots.group([short, long, other], notes)
    seeds = groups["FetchPush"]["her"]
    assert sorted((c.seed, len(c.epochs)) for c in seeds) == [(1, 4), (2, 3)]
    assert len(notes) == 1 and "counted once, with the longer run" in notes[0]
    table = plots.aggregate(seeds)  # the table: epochs every seed reached
    assert table.epochs.tolist() == [1, 2, 3] and table.n_seeds == 2
    drawn = plots.aggregate(seeds, every_seed=False)  # the figure: to each run's end
    assert drawn.epochs.tolist() == [1, 2, 3, 4]
    assert drawn.mean.tolist() == pytest.approx([0.3, 0.4, 0.5, 0.4])


def test_reference_for_a_task_without_authors_data_says_so(tmp_path: Path, capsys) -> None:
    run = _write_run(tmp_path, "her", 1, [0.0, 0.5], task="reach")
    assert main(["plot", str(run), "-o", str(tmp_path / "f.png"), "--reference"]) == 0
    err = capsys.readouterr().err
    assert "--reference: the authors published no curves for FetchReach" in err

def test_a_lockstep_run_is_its_own_method_next_to_the_asynchronous_one(tmp_path: Path) -> None:
    runs = [_write_run(tmp_path, "her-cs", 1, [0.1, 0.3, 0.7]),
            _write_lockstep_run(tmp_path, "her-cs", 1, [0.2, 0.6, 0.9])]
    groups = plots.group(plots.load_run(r) for r in runs)
    assert list(groups["FetchPush"]) == ["her-cs", "her-cs/lockstep"]
    text = plot_tables.tables(groups)
    assert "| HER-CS | 1 | 3 | – | – |" in text  # ma 0.1, 0.2, 0.367: none past 0.5
    # ma 0.2, 0.4, 0.567 → epoch 3 − 1
    assert "| HER-CS, lockstep (as the authors' code) | 1 | 3 | 2 | – |" in text


def test_a_bf16_run_is_its_own_method_and_combines_with_lockstep(tmp_path: Path) -> None:
    runs = [_write_run(tmp_path, "her-ebp-cs", 1, [0.1, 0.3, 0.7]),
            _write_variant_run(tmp_path, "her-ebp-cs", 1, [0.2, 0.6, 0.9], precision="bf16"),
            _write_variant_run(tmp_path, "her-ebp-cs", 1, [0.0, 0.0, 0.1],
                               schedule="lockstep", precision="bf16")]
    groups = plots.group(plots.load_run(r) for r in runs)
    assert sorted(groups["FetchPush"]) == [
        "her-ebp-cs", "her-ebp-cs/bf16", "her-ebp-cs/lockstep/bf16"]
    text = plot_tables.tables(groups)
    assert "| HER-EBP-CS, bf16 learner, ε = 10⁻⁶ | 1 | 3 | 2 | – |" in text
    assert ("| HER-EBP-CS, lockstep (as the authors' code), bf16 learner, ε = 10⁻⁶ | 1 | 3 | – "
            "| – |") in text


def test_a_v1_run_is_its_own_method_never_averaged_with_v4(tmp_path: Path) -> None:
    """Runs on the authors' Fetch*-v1 (task.env_version) are grouped apart from the v4 runs of
    the same method and seed, labelled "(v1)", alone or with a schedule variant; a config.yaml
    without env_version is v4."""
    runs = [_write_run(tmp_path, "her-ebp-cs", 1, [0.1, 0.3, 0.7]),
            _write_variant_run(tmp_path, "her-ebp-cs", 1, [0.2, 0.6, 0.9]),
            _write_variant_run(tmp_path, "her-ebp-cs", 2, [0.0, 0.8, 1.0], schedule="lockstep")]
    for run, version in zip(runs[1:], ("v1", "v1"), strict=True):
        config = yaml.safe_load(RunDir(run).config.read_text())
        config["task"]["env_version"] = version
        RunDir(run).config.write_text(yaml.safe_dump(config))
    groups = plots.group(plots.load_run(r) for r in runs)
    assert list(groups["FetchPush"]) == ["her-ebp-cs", "her-ebp-cs/lockstep/v1", "her-ebp-cs/v1"]
    assert [len(c) for c in groups["FetchPush"].values()] == [1, 1, 1]
    text = plot_tables.tables(groups)
    assert "| HER-EBP-CS, ε = 10⁻⁶ | 1 | 3 | – | – |" in text  # v4's default today: 10⁻³
    assert "| HER-EBP-CS, authors' simulator (v1) | 1 | 3 | 2 | – |" in text
    assert ("| HER-EBP-CS, lockstep (as the authors' code), authors' simulator (v1) | 1 | 3 | 2 "
            "| – |") in text  # ma 0, .4, .6
    assert plots.method_key("her-cs", "lockstep", "bf16", "v1") == "her-cs/lockstep/bf16/v1"
    assert plots.method_label("her-cs/lockstep/bf16/v1") == (
        "HER-CS, lockstep (as the authors' code), bf16 learner, authors' simulator (v1)")
    assert plots.method_key("her-cs", env_version="v4") == "her-cs"
    eps = plots.method_key("her-ebp-cs", energy_epsilon=1e-3, torquescale=4.0)
    assert eps == "her-ebp-cs/eps0.001/ts4"
    assert plots.method_label(eps) == "HER-EBP-CS, ε = 10⁻³, weld torquescale 4"
    assert plots.energy_epsilon({"energy": {"epsilon": 0.001}}) == 0.001
    assert plots.energy_epsilon({}) == plots.EPSILON_UNMARKED == 1e-6
    with_reference = plot_tables.tables(groups, plots.group(plots.load_reference()))
    assert "| HER-EBP-CS, authors' simulator (v1) (ours) | 1 | 3 |" in with_reference
    assert "| HER-EBP-CS (authors) | 5 | 100 | 22 | 31 |" in with_reference


def test_figure_2_has_six_panels_and_a_table_per_panel(tmp_path: Path, capsys) -> None:
    runs = [_write_run(tmp_path, "her-ebp", 1, [0.0] * 5 + [1.0] * 10),
            _write_lockstep_run(tmp_path, "her-cs", 1, [0.0] * 3 + [1.0] * 12),
            # a precision variant is compared in docs/PERFORMANCE.md, not drawn in Fig. 2
            _write_variant_run(tmp_path, "her-ebp", 1, [1.0] * 15, precision="bf16")]
    out, table = tmp_path / "fig2.png", tmp_path / "fig2.md"
    assert main(["plot", "--figure", "2", *map(str, runs), "-o", str(out), "--table",
                 str(table)]) == 0
    from PIL import Image

    with Image.open(out) as image:
        assert image.size == (3 * plots.PANEL_W * plots.DPI, 2 * plots.PANEL_H * plots.DPI)
    text = table.read_text()
    titles = [line for line in text.splitlines() if line.startswith("### ")]
    assert titles == [f"### {task}: {pair}"
                      for pair in ("HER vs HER-CS", "HER-EBP vs HER-EBP-CS")
                      for task in plot_tables.fig2_layout().tasks]
    push_her = text.split("### FetchPush: HER vs HER-CS")[1].split("###")[0]
    # trailing means (e − 3)/e pass .5 at epoch 7, .9 at epoch 13 (counted from 0: 6, 12)
    assert "| HER-CS, lockstep (as the authors' code) (ours) | 1 | 15 | 6 | 12 |" in push_her
    assert "| HER (authors) | 5 | 200 | 55 | 95 |" in push_her
    assert "bf16" not in text
    assert text.count("No runs of ours yet.") == 4  # Pick and Slide, both rows
    assert text in capsys.readouterr().out


def test_the_paper_figure_layout_is_data_the_authors_published_curves_cover() -> None:
    """Fig. 2's rows and columns come from hercs/apps/plots/data/fig2.yaml: each pair's
    methods are hercs methods, and the authors published curves of both on every task."""
    layout = plot_tables.fig2_layout()
    published = plots.group(plots.load_reference())
    assert layout.epochs == 200 and len(layout.rows) * len(layout.tasks) == 6
    for pair in layout.rows:
        for task in layout.tasks:
            assert all(m in METHODS and m in published[task] for m in pair), (task, pair)


def test_a_layout_file_is_read_or_refused_by_name(tmp_path: Path) -> None:
    good, bad = tmp_path / "good.yaml", tmp_path / "bad.yaml"
    good.write_text("tasks: [A, B]\nrows: [[x, y]]\nepochs: 5\n")
    bad.write_text("tasks: [A]\n")
    assert plot_tables.read_layout(good) == plot_tables.FigureLayout(("A", "B"), (("x", "y"),), 5)
    with pytest.raises(plots.PlotError, match=r"bad\.yaml: not a figure layout"):
        plot_tables.read_layout(bad)


def test_a_folder_named_twice_is_read_once_with_one_line_saying_so(tmp_path: Path,
                                                                   capsys) -> None:
    """The README's `hercs plot runs/push-her-* runs/push-her-cs-* --reference`: the first
    glob also matches the HER-CS folders, which used to give one warning per folder."""
    runs = [_write_run(tmp_path, m, s, c) for (m, s), c in CURVES.items()]
    her, cs = runs[:2], runs[2:]
    argv = ["plot", *map(str, [*her, *cs]), *map(str, cs), f"{cs[0]}/",
            "-o", str(tmp_path / "f.png")]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        "hercs plot: 2 run folders named more than once (overlapping globs?): each read once"]
    assert "| HER-CS | 2 | 6 |" in captured.out  # two seeds, not four
    assert plot_command.distinct_run_dirs([*her, her[0], f"{her[1]}/"]) == (her, 2)


@pytest.mark.parametrize("band", ["ci", "minmax", "both"])
def test_cli_band_option(run_dirs: list[Path], tmp_path: Path, band: str) -> None:
    out = tmp_path / f"{band}.png"
    assert main(["plot", *map(str, run_dirs), "-o", str(out), "--band", band]) == 0
    assert out.is_file()


def test_cli_refuses_an_unknown_band(run_dirs: list[Path], tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["plot", str(run_dirs[0]), "-o", str(tmp_path / "f.png"), "--band", "sd"])
    assert exit_info.value.code == 2
    assert "invalid choice: 'sd'" in capsys.readouterr().err
    with pytest.raises(plots.PlotError, match="got 'sd'"):
        plot_command.run_plot([str(run_dirs[0])], str(tmp_path / "f.png"), band="sd")


def test_figure_2_caption_names_the_band_drawn() -> None:
    ref = plots.group(plots.load_reference(plots.REFERENCE_CSV))
    assert "are the bootstrap 95 % interval of their mean" in plot_tables.fig2_text({}, ref)
    both = plot_tables.fig2_text({}, ref, band="both")
    assert "interval of their mean (seeds resampled, a fixed RNG seed) and, lighter, their " \
           "min–max" in both
    assert "are their min–max." in plot_tables.fig2_text({}, ref, band="minmax")


def _drawn(monkeypatch: pytest.MonkeyPatch, draw: Callable[[], object]) -> Any:
    """The matplotlib figure `draw()` saved (plt.close is kept from discarding it)."""
    import matplotlib.pyplot as plt

    figures: list[Any] = []
    monkeypatch.setattr(plt, "close", figures.append)
    draw()
    [fig] = figures
    return fig


def _legends_inside_and_looks(fig: Any) -> tuple[bool, list[tuple[str, tuple[Any, ...]]]]:
    """Whether every legend lies inside the figure, and (label, look) of each of our series'
    lines, its look (colour, dash pattern, marker) (`line_look`)."""
    renderer = fig.canvas.get_renderer()
    inside = all(fig.bbox.x0 <= box.x0 and box.x1 <= fig.bbox.x1 and
                 fig.bbox.y0 <= box.y0 and box.y1 <= fig.bbox.y1
                 for ax in fig.axes if ax.get_legend() is not None
                 for box in [ax.get_legend().get_window_extent(renderer)])
    ours = [(line.get_label(), line_look(line)) for ax in fig.axes for line in ax.lines
            if "authors' published" not in line.get_label()]
    return inside, ours


def test_a_legend_of_many_groups_grows_the_figure_instead_of_being_cut(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """The README's old example drew 21 series and cut its legend's last entry in half."""
    settings = [{}, {"training": {"schedule": "lockstep"}}, {"learner": {"precision": "bf16"}},
                {"task": {"name": "push", "env_version": "v1"}},
                {"training": {"schedule": "lockstep"}, "learner": {"precision": "bf16"}}]
    dirs = []
    for i in range(20):  # 4 methods × 5 settings: 20 groups
        method = list(METHODS)[i % 4]
        (tmp_path / f"r{i}").mkdir()
        run = _write_run(tmp_path / f"r{i}", method, 1, [0.07 * (i % 13)] * 12)
        config = yaml.safe_load(RunDir(run).config.read_text())
        config.update(settings[i // 4])
        RunDir(run).config.write_text(yaml.safe_dump(config))
        dirs.append(run)
    fig = _drawn(monkeypatch, lambda: plot_command.run_plot(
        [str(d) for d in dirs], str(tmp_path / "many.png"), reference=True,
        choice=SeriesChoice(every=True)))
    inside, ours = _legends_inside_and_looks(fig)
    assert len(ours) == 20 and inside
    assert fig.get_figheight() > plots.PANEL_H  # grown, not clipped
    # a colour per method, and the five settings of each apart by their line style
    assert len({look[0] for _, look in ours}) == 4
    assert len({look[:2] for _, look in ours}) == 20
    assert "not drawn" not in capsys.readouterr().err  # --all-series: nothing left out


def test_the_readmes_plot_examples_are_readable(monkeypatch: pytest.MonkeyPatch,
                                                tmp_path: Path) -> None:
    """Every `hercs plot` line of the README that draws committed runs: at most MAX_SERIES
    series, every legend inside the image and no colour on two of our groups."""
    readme = (REPO / "README.md").read_text()
    commands = [line.split("#")[0].split() for line in readme.splitlines()
                if re.match(r"^(\.venv/bin/)?hercs plot docs/results/runs/", line)]
    assert commands, "the README shows no plot of the committed runs"
    for words in commands:
        globs = [w for w in words[2:] if w.startswith("docs/results/runs/")]
        folders = sorted({str(p) for g in globs for p in REPO.glob(g) if p.is_dir()})
        assert folders, f"{' '.join(words)}: matches no committed run"
        reference = "--reference" in words
        fig = _drawn(monkeypatch, lambda folders=folders, reference=reference:
                     plot_command.run_plot(folders, str(tmp_path / "readme.png"),
                                           reference=reference))
        inside, ours = _legends_inside_and_looks(fig)
        assert inside, f"{' '.join(words)}: a legend runs off the image"
        looks = [look[:2] for _, look in ours]  # (colour, line style)
        assert len(set(looks)) == len(looks) <= MAX_SERIES, ours


def test_a_callers_variant_groups_runs_apart_and_is_labelled_as_its_note(tmp_path: Path) -> None:
    """`hercs plot` groups by settings alone; a caller's `variant_of` (a study's) adds its
    own variant, labelled by its note."""
    old = _write_run(tmp_path, "her-cs", 1, [0.1, 0.2])
    new = _write_run(tmp_path, "her-cs", 2, [0.3, 0.4])
    config = yaml.safe_load(RunDir(old).config.read_text())
    RunDir(old).config.write_text(yaml.safe_dump({**config, "era": "old"}))
    assert set(plots.group(plots.load_run(r) for r in (old, new))["FetchPush"]) == {"her-cs"}

    def era(run_config: dict[str, Any]) -> str:
        return "old" if run_config.get("era") == "old" else ""

    ours = plots.group(plots.load_run(r, era) for r in (old, new))
    assert set(ours["FetchPush"]) == {"her-cs", "her-cs/old"}
    assert plots.method_key("her-cs", "lockstep", variant="old", env_version="v1") == (
        "her-cs/lockstep/old/v1")
    assert plots.method_label("her-cs/lockstep/old/v1", {"old": "before"}) == (
        "HER-CS, lockstep (as the authors' code), before, authors' simulator (v1)")
    assert plots.method_label("her-cs/old") == "HER-CS, old"  # no note given: as it is
