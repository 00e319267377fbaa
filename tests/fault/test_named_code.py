"""A run folder cannot make hercs import code (issue 57): a checkpoint whose embedded config
names `pytest:main` (which would collect a conftest.py planted beside it) or `fetchenv:make`
(a module planted in the folder) is refused by `hercs eval`, `hercs.load_policy` and `hercs up
--resume`, with the folder on sys.path, and the planted code's marker never appears; the
same name given by the user (`task=`, `--trust-task`) is imported."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from hercs.rl.code_names import ANY, TRUST_ENV, check_may_import, imported_module, trust_task

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
SHIPPED = REPO / "docs" / "results" / "runs" / "push-her-s1"
COMMAND_TIMEOUT_S = 120


def planted_run(tmp_path: Path, task_name: str, module_file: str) -> tuple[Path, Path]:
    """A copy of a shipped run whose best.pt's embedded config names `task_name` (rewritten
    as a data-only checkpoint), with `module_file` planted beside it creating a marker."""
    run = tmp_path / "run"
    run.mkdir()
    for name in ("config.yaml", "metrics.csv"):
        shutil.copy(SHIPPED / name, run / name)
    (run / "checkpoints").mkdir()
    state = torch.load(SHIPPED / "checkpoints" / "best.pt", weights_only=True)
    state["config"]["task"]["name"] = task_name
    torch.save(state, run / "checkpoints" / "best.pt")
    marker = tmp_path / "MARKER"
    (run / module_file).write_text(f"open({str(marker)!r}, 'w').close()\n"
                                   "def make(**kwargs):\n    raise SystemExit(7)\n")
    return run, marker


def run_in(folder: Path, argv: list[str]) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != TRUST_ENV}
    env["PYTHONPATH"] = os.pathsep.join([str(folder), str(REPO)])  # the folder is importable
    return subprocess.run(argv, cwd=folder, env=env, capture_output=True, text=True,
                          timeout=COMMAND_TIMEOUT_S)


def test_hercs_eval_does_not_run_a_conftest_through_pytest_main(tmp_path: Path) -> None:
    run, marker = planted_run(tmp_path, "pytest:main", "conftest.py")
    done = run_in(run, [sys.executable, "-m", "hercs.apps.cli", "eval", str(run),
                        "--episodes", "1"])
    assert done.returncode == 2, done.stdout + done.stderr
    assert "'pytest:main' names code to import (module 'pytest')" in done.stderr, done.stderr
    assert "--trust-task" in done.stderr, done.stderr
    assert not marker.exists(), "the conftest beside the checkpoint ran"


def test_load_policy_does_not_import_a_module_planted_in_the_working_directory(
        tmp_path: Path) -> None:
    run, marker = planted_run(tmp_path, "fetchenv:make", "fetchenv.py")
    probe = ("import hercs\n"
             "try:\n    hercs.load_policy('.')\n"
             "except hercs.ConfigError as exc:\n    print('REFUSED', exc)\n")
    done = run_in(run, [sys.executable, "-c", probe])
    assert done.returncode == 0, done.stdout + done.stderr
    assert "REFUSED" in done.stdout and "'fetchenv:make' names code" in done.stdout, done.stdout
    assert not marker.exists(), "fetchenv.py was imported because a file named it"
    # named by the user, the same factory is imported: the refusal is about who named it
    trusted = run_in(run, [sys.executable, "-c",
                           "import hercs; hercs.load_policy('.', task='fetchenv:make')"])
    assert marker.exists(), trusted.stdout + trusted.stderr
    assert trusted.returncode == 7, trusted.stdout + trusted.stderr  # its make() ran


def test_a_resume_of_a_folder_naming_code_is_refused_before_anything_changes(
        tmp_path: Path) -> None:
    run, marker = planted_run(tmp_path, "fetchenv:make", "fetchenv.py")
    config = yaml.safe_load((run / "config.yaml").read_text())
    config["task"]["name"] = "fetchenv:make"
    (run / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    before = {p.name: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    done = run_in(run, [sys.executable, "-m", "hercs.apps.cli", "up", "--resume", str(run)])
    assert done.returncode == 2, done.stdout + done.stderr
    assert "'fetchenv:make' names code to import" in done.stderr, done.stderr
    assert not marker.exists()
    assert {p.name: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("name, module", [
    ("pytest:main", "pytest"), ("my.pkg.envs:make_env", "my.pkg.envs"),
    ("evil:Env-v0", "evil"), ("pkg.sub:Maze_Open-v3", "pkg.sub"),
    ("push", None), ("FetchPush-v4", None), ("PointMaze_UMaze-v3", None)],
    ids=["factory", "dotted-factory", "gym-module-id", "gym-dotted-id", "preset",
         "fetch-id", "gym-id"])
def test_which_names_import_code(name: str, module: str | None) -> None:
    assert imported_module(name) == module


def test_a_name_is_trusted_only_once_named(monkeypatch: pytest.MonkeyPatch) -> None:
    from hercs.errors import ConfigError

    monkeypatch.delenv(TRUST_ENV, raising=False)
    with pytest.raises(ConfigError, match="names code to import"):
        check_may_import("mine:make")
    trust_task("mine:make")
    check_may_import("mine:make")
    with pytest.raises(ConfigError):  # another name stays refused
        check_may_import("other:make")
    trust_task(ANY)
    check_may_import("other:make")
