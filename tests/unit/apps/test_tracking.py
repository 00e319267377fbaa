"""What the trackers are sent, from a run's own files (hercs/apps/tracking/rows.py), and how
`--track` reaches the config of `hercs up`, `hercs sweep` and `hercs.up`."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from hercs.apps.cli.config_flags import resolve_config
from hercs.apps.cli.main import build_parser
from hercs.apps.cli.run_handle import _built
from hercs.apps.sweep.grid import tracking_overrides
from hercs.apps.tracking.rows import complete_rows, epoch_scalars, flat_hyperparameters
from hercs.apps.tracking.session import check_installed
from hercs.config import HercsConfig, TrackingConfig, load_yaml, save_yaml
from hercs.errors import ConfigError

ROW = {"epoch": "3", "success_rate": "0.45", "critic_loss": "0.125", "env_steps": "3000",
       "cluster_sizes": "12;0;7", "cluster_share": "0.5000;0.2500;0.2500",
       "rejects": "stale_policy:2", "policy_lag_p50": "nan", "batch_wait_s": ""}


def test_a_row_is_its_numbers_by_panel_and_the_cluster_model_per_cluster() -> None:
    assert epoch_scalars(ROW) == {
        "eval/success_rate": 0.45, "loss/critic_loss": 0.125, "progress/env_steps": 3000.0,
        "clusters/size_0": 12.0, "clusters/size_1": 0.0, "clusters/size_2": 7.0,
        "clusters/share_0": 0.5, "clusters/share_1": 0.25, "clusters/share_2": 0.25}


def test_a_row_still_being_written_waits_for_its_line_end() -> None:
    text = "epoch,success_rate\n1,0.5\n2,0.6\n3,0."
    assert [r["epoch"] for r in complete_rows(text)] == ["1", "2"]
    assert [r["epoch"] for r in complete_rows(text + "7\n")] == ["1", "2", "3"]
    assert complete_rows("epoch,success_rate") == []


def test_the_config_is_flat_as_set_spells_it_and_reads_back_the_same() -> None:
    config = HercsConfig(tracking=TrackingConfig(backends=["wandb", "mlflow"]))
    flat = flat_hyperparameters(config.resolved().to_dict())
    assert flat["tracking.backends"] == "[wandb, mlflow]"
    assert flat["ddpg.lr_actor"] == config.ddpg.lr_actor and flat["run.method"] == "her-cs"
    assert len(flat) == sum(len(s) for s in config.to_dict().values())
    from hercs.config import apply_overrides

    again = apply_overrides(HercsConfig(), [f"{k}={v}" for k, v in flat.items()
                                            if not k.startswith("run.name")])
    assert again.resolved().to_dict() == config.resolved().to_dict()


def _up(*argv: str) -> HercsConfig:
    return resolve_config(build_parser()[0].parse_args(["up", *argv]))


def test_track_is_repeatable_and_tensorboard_is_its_older_spelling() -> None:
    assert _up("--track", "wandb", "--track", "mlflow").tracking.backends == ["wandb", "mlflow"]
    assert _up("--tensorboard").tracking.backends == ["tensorboard"]
    assert _up("--tensorboard", "--track", "tensorboard").tracking.backends == ["tensorboard"]
    assert _up("--track", "wandb", "--set", "tracking.project=lab").tracking.project == "lab"


def test_an_unknown_tracker_is_refused_naming_the_known_ones(
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        build_parser()[0].parse_args(["up", "--track", "comet"])
    assert exc.value.code == 2
    assert "--track: invalid choice: 'comet' (choose from 'tensorboard', 'wandb', 'mlflow')" in \
        capsys.readouterr().err


def test_a_resume_adds_a_tracker_to_those_the_run_had(tmp_path: Path) -> None:
    from hercs.config import save_yaml

    save_yaml(HercsConfig(tracking=TrackingConfig(backends=["wandb"])), tmp_path / "config.yaml")
    assert _up("--resume", str(tmp_path), "--track", "mlflow").tracking.backends == \
        ["wandb", "mlflow"]


def test_a_saved_run_tensorboard_field_still_loads(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("run:\n  tensorboard: false\n")
    assert load_yaml(tmp_path / "c.yaml").tracking.backends == []


def test_python_track_is_the_flag(tmp_path: Path) -> None:
    none = dict.fromkeys(["method", "epochs", "seed", "actors", "name", "run_dir", "config"])
    one = _built(task="reach", overrides=(), listen="tcp/127.0.0.1:0", track="wandb", **none)
    assert one.tracking.backends == _up("--task", "reach", "--track", "wandb").tracking.backends
    save_yaml(HercsConfig(tracking=TrackingConfig(backends=["wandb"])), tmp_path / "c.yaml")
    two = _built(task=None, overrides=(), listen="tcp/127.0.0.1:0", track=["mlflow"],
                 **{**none, "config": tmp_path / "c.yaml"})
    assert two.tracking.backends == ["wandb", "mlflow"]


def test_a_sweep_groups_its_cells_by_its_folder_unless_told_a_group() -> None:
    root = Path("/x/runs/lr-sweep")
    assert tracking_overrides(["wandb"], [], root) == ["tracking.backends=[wandb]",
                                                       "tracking.group=lr-sweep"]
    assert tracking_overrides(["wandb"], ["tracking.group = g"], root) == \
        ["tracking.backends=[wandb]"]
    assert tracking_overrides([], [], root) == []


@pytest.mark.parametrize("name", ["wandb", "mlflow"])
def test_a_tracker_whose_package_is_missing_is_refused_naming_the_extra(
        monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    monkeypatch.setitem(sys.modules, name, None)  # the import system's own "not importable"
    with pytest.raises(ConfigError, match=rf"^tracking.backends: {name} needs the {name} "
                       rf"package, which is not installed; pip install 'hercs\[{name}\]'$"):
        check_installed(TrackingConfig(backends=[name]))


def test_a_missing_tracker_package_stops_hercs_up_before_anything_starts(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    from hercs.apps.cli.main import main

    monkeypatch.setitem(sys.modules, "mlflow", None)
    code = main(["up", "--task", "reach", "--track", "mlflow", "--run-dir", str(tmp_path)])
    assert code == 2 and list(tmp_path.iterdir()) == []
    assert "pip install 'hercs[mlflow]'" in capsys.readouterr().err
