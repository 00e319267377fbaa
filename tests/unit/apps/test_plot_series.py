"""`hercs plot`'s series (hercs/apps/plots/series.py), run as a user runs it: every setting that
differs is in the key and the label, a panel draws at most MAX_SERIES by default and stderr
names the rest, `--series` / `--all-series` draw others, `--reference` only the methods drawn."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from hercs.apps.plots import command as plot_command
from hercs.apps.plots.series import MAX_SERIES, SeriesChoice, method_label, series_key
from hercs.run.rundir import RunDir
from tests.support import REPO
from tests.unit.apps.plot_runs import _write_run

OLD_LAG = {"replay": {"rate_tolerance_updates": 80.0}}  # saved before learner.prefetch_depth
SETTINGS: dict[str, dict[str, Any]] = {
    "plain": {}, "lockstep": {"training": {"schedule": "lockstep"}},
    "v1": {"task": {"name": "push", "env_version": "v1"}}, "old-lag": OLD_LAG,
}


def _runs(root: Path, methods: tuple[str, ...] = ("her", "her-cs")) -> list[Path]:
    """One seed of each method in each of SETTINGS: 8 series on one panel."""
    runs = []
    for name, extra in SETTINGS.items():
        for i, method in enumerate(methods):
            (root / name).mkdir(exist_ok=True)
            run = _write_run(root / name, method, 1, [0.1 * (e + i) for e in range(8)])
            config = yaml.safe_load(RunDir(run).config.read_text())
            RunDir(run).config.write_text(yaml.safe_dump({**config, **extra}))
            runs.append(run)
    return runs


def _plot(*words: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hercs.apps.cli", "plot", *words], cwd=REPO,
                          capture_output=True, text=True, timeout=300)


def test_every_setting_is_in_the_key_and_the_label() -> None:
    base = {"run": {"method": "her-ebp-cs", "seed": 1}, "task": {"name": "push"}}
    config = {**base, "energy": {"epsilon": 1e-3}, "learner": {"precision": "bf16"},
              "cluster": {"share_rule": "reference"}, **OLD_LAG}
    key = series_key(config)
    assert key == "her-ebp-cs/bf16/lag=80,3,2,-1/eps0.001/share=reference"
    assert method_label(key) == ("HER-EBP-CS, bf16 learner, no lag bound, prefetch 3, actor "
                                 "queue 2, rate tolerance 80, ε = 10⁻³, reference share rule")
    peer = {**base, "training": {"schedule": "authors-code"}, "task": {"name": "push",
                                                                      "env_version": "v1"}}
    assert series_key(peer) == "her-ebp-cs/authors-code/v1"
    assert series_key(base) == "her-ebp-cs"  # a config written by hand: the defaults


@pytest.mark.slow  # three `hercs plot` processes
def test_a_panel_draws_six_series_and_stderr_names_the_rest(tmp_path: Path) -> None:
    runs = [str(r) for r in _runs(tmp_path)]
    done = _plot(*runs, "-o", str(tmp_path / "f.png"), "--table", str(tmp_path / "t.md"))
    assert done.returncode == 0, done.stderr
    assert ("FetchPush: 2 more series not drawn (at most 6 a panel by default): HER, "
            "lockstep (as the authors' code); HER-CS, lockstep (as the authors' code); "
            "`--all-series` draws every one") in done.stderr
    table = (tmp_path / "t.md").read_text()  # the table has every series
    for label in ("HER", "HER-CS, lockstep (as the authors' code)",
                  "HER-CS, authors' simulator (v1)",
                  "HER-CS, no lag bound, prefetch 3, actor queue 2, rate tolerance 80"):
        assert f"| {label} | 1 |" in table
    chosen = _plot(*runs, "-o", str(tmp_path / "g.png"), "--series", "*lag*")
    assert chosen.returncode == 0 and "not drawn" not in chosen.stderr
    wrong = _plot(*runs, "-o", str(tmp_path / "h.png"), "--series", "*lag9*")
    assert wrong.returncode == 2 and not (tmp_path / "h.png").exists()
    assert "--series *lag9*: matches no series; the runs given have her " in wrong.stderr


def _legend(monkeypatch: pytest.MonkeyPatch, draw: Any) -> list[str]:
    import matplotlib.pyplot as plt

    figures: list[Any] = []
    monkeypatch.setattr(plt, "close", figures.append)
    draw()
    [fig] = figures
    return [line.get_label() for ax in fig.axes for line in ax.lines]


def test_the_default_choice_and_the_flags_pick_what_is_drawn(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    runs = [str(r) for r in _runs(tmp_path)]
    out = str(tmp_path / "f.png")

    def drawn(**kwargs: Any) -> list[str]:
        return _legend(monkeypatch, lambda: plot_command.run_plot(runs, out, **kwargs))

    default = drawn(reference=True)  # two methods' authors' curves count among the six
    assert len(default) == MAX_SERIES and sum("authors' published" in x for x in default) == 2
    # plain, then v1: the authors' environment
    assert "HER-CS, authors' simulator (v1), 1 seed" in [x.replace("\n", " ") for x in default]
    assert not any("lag" in x or "lockstep" in x for x in default)
    assert len(drawn(choice=SeriesChoice(every=True))) == 8
    assert [x.replace("\n", " ") for x in drawn(choice=SeriesChoice(("*lockstep*",
                                                                  "her-cs/v1")))] == [
        "HER, lockstep (as the authors' code), 1 seed",
        "HER-CS, lockstep (as the authors' code), 1 seed",
        "HER-CS, authors' simulator (v1), 1 seed"]
    capsys.readouterr()


def test_reference_draws_the_authors_curves_of_the_methods_drawn_only(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    runs = [str(r) for r in _runs(tmp_path, ("her-cs",))]
    out = str(tmp_path / "f.png")
    legend = _legend(monkeypatch, lambda: plot_command.run_plot(runs, out, reference=True))
    assert [x for x in legend if "published" in x] == ["HER-CS, authors' published (5 seeds)"]
    done = _plot(*runs, "-o", out, "--reference")
    assert done.returncode == 0 and "| HER-CS (authors) |" in done.stdout
    assert "| HER (authors) |" not in done.stdout and "HER-EBP" not in done.stdout
