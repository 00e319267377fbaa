"""Files in a run folder are data (issue 46): a crafted `best.pt`, `learner.pt`, episode log or
config.yaml that would run code when opened is refused with a message naming it, through the
commands and the Python API a user runs, and its marker file never appears. Each crafted file
is first shown to be hostile: opened the unsafe way, a copy of it creates its marker."""

from __future__ import annotations

import contextlib
import pickle
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
import yaml

import hercs
from hercs.apps.launch.resume_check import CannotResume
from hercs.errors import ConfigError, HercsError
from hercs.run.checkpoint_file import CheckpointError
from hercs.run.rundir import RunDir
from hercs.run.runlog import EpisodeLogError
from tests.run_dirs import make_run

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
COMMAND_TIMEOUT_S = 120


class RunsCode:
    """Unpickled by a plain unpickler, it creates `marker`: what a crafted file does."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Callable[..., object], tuple[str]]:
        return exec, (f"open({str(self.marker)!r}, 'w').close()",)


def crafted_checkpoint(marker: Path, form: str) -> bytes:
    """A checkpoint that runs code: torch's own file format with the payload where the
    weights go, or a bare pickle of it."""
    if form == "bare-pickle":
        return pickle.dumps({"policy": RunsCode(marker)}, protocol=2)
    path = marker.with_suffix(".tmp")
    torch.save({"policy": RunsCode(marker), "learner": RunsCode(marker), "epoch": 1}, path)
    data = path.read_bytes()
    path.unlink()
    return data


def crafted_yaml(marker: Path) -> str:
    return f"run: !!python/object/apply:builtins.exec [\"open({str(marker)!r}, 'w').close()\"]\n"


def assert_hostile_checkpoint(tmp_path: Path, form: str) -> None:
    control = tmp_path / "control-marker"
    path = tmp_path / "control.pt"
    path.write_bytes(crafted_checkpoint(control, form))
    # a bare pickle then fails torch's magic-number check: after its payload has run
    with contextlib.suppress(RuntimeError):
        torch.load(path, weights_only=False)
    assert control.exists(), "the crafted file does not run its code even when unpickled"


def hercs_command(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hercs.apps.cli", *argv], cwd=cwd,
                          capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S)


def snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*"))}


@pytest.fixture
def run(tmp_path: Path) -> Path:
    """A real run folder (a small learner's checkpoint of epoch 2, metrics rows, config)."""
    folder = tmp_path / "runs" / "shared"
    make_run(folder, epochs=4, trained=2, checkpoint=2)
    return folder


@pytest.mark.parametrize("form", ["torch-file", "bare-pickle"])
@pytest.mark.parametrize("name", ["best", "latest"])
def test_a_crafted_checkpoint_is_refused_by_load_policy_and_runs_nothing(
        run: Path, tmp_path: Path, name: str, form: str) -> None:
    assert_hostile_checkpoint(tmp_path, form)
    marker = tmp_path / "marker"
    RunDir(run).checkpoint(name).write_bytes(crafted_checkpoint(marker, form))
    with pytest.raises(CheckpointError, match=r"not a readable checkpoint") as refused:
        hercs.load_policy(run, name)
    assert str(RunDir(run).checkpoint(name)) in str(refused.value)
    assert "nothing in it was run" in str(refused.value).lower()
    assert not marker.exists()


@pytest.mark.parametrize(("name", "form"), [("best", "torch-file"), ("best", "bare-pickle"),
                                            ("latest", "torch-file")])
def test_hercs_eval_refuses_a_crafted_checkpoint_with_exit_2(
        run: Path, tmp_path: Path, name: str, form: str) -> None:
    marker = tmp_path / "marker"
    path = RunDir(run).checkpoint(name)
    path.write_bytes(crafted_checkpoint(marker, form))
    done = hercs_command("eval", str(run), "--checkpoint", name, "--episodes", "1",
                         cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.startswith(f"hercs eval: {path}: not a readable checkpoint"), done.stderr
    assert "Traceback" not in done.stderr and "weights_only" not in done.stderr, done.stderr
    assert not marker.exists()


def test_hercs_up_resume_refuses_a_crafted_learner_checkpoint_before_anything_starts(
        run: Path, tmp_path: Path) -> None:
    marker = tmp_path / "marker"
    latest = RunDir(run).checkpoint("latest")
    latest.write_bytes(crafted_checkpoint(marker, "torch-file"))
    before = snapshot(run)
    done = hercs_command("up", "--resume", str(run), cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.startswith(f"hercs up: {latest}: not a readable learner checkpoint: "
                                  "it names exec, which is neither a tensor nor plain "
                                  "data"), done.stderr
    assert "add --restart" in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert snapshot(run) == before, "a refused resume changed the run folder"
    assert not marker.exists()
    with pytest.raises(CannotResume, match="not a readable learner checkpoint"):
        hercs.resume(run)
    assert not marker.exists()


def test_a_crafted_episode_log_is_refused_by_view_read_episodes_and_resume(
        run: Path, tmp_path: Path) -> None:
    """The episode log (episodes, cluster models and the replay states a restarted replay
    starts from) is MCAP with protobuf messages: a pickle there is no MCAP file."""
    marker = tmp_path / "marker"
    log = RunDir(run).episode_log
    log.write_bytes(pickle.dumps(RunsCode(marker)))
    with pytest.raises(EpisodeLogError, match="is not an MCAP file"):
        list(hercs.read_episodes(run))

    view = hercs_command("view", str(run), "--save", str(tmp_path / "out.rrd"), cwd=tmp_path)
    assert view.returncode == 2, view.stdout + view.stderr
    assert view.stderr.startswith(f"hercs view: {log} is not an MCAP file"), view.stderr

    before = snapshot(run)
    up = hercs_command("up", "--resume", str(run), cwd=tmp_path)
    assert up.returncode == 2, up.stdout + up.stderr
    assert up.stderr.startswith(f"hercs up: {log} is not an MCAP file"), up.stderr
    assert "The replay could not reload its episodes from it" in up.stderr, up.stderr
    assert snapshot(run) == before
    with pytest.raises(CannotResume, match="is not an MCAP file"):
        hercs.resume(run)
    assert not marker.exists()


def test_a_crafted_config_yaml_is_refused_by_resume_and_runs_nothing(
        run: Path, tmp_path: Path) -> None:
    control = tmp_path / "control-marker"
    yaml.unsafe_load(crafted_yaml(control))
    assert control.exists(), "the crafted YAML does not run its code even when loaded unsafely"
    marker = tmp_path / "marker"
    RunDir(run).config.write_text(crafted_yaml(marker))

    done = hercs_command("up", "--resume", str(run), cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "could not determine a constructor for the tag" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
    with pytest.raises(ConfigError, match="not valid YAML"):
        hercs.resume(run)
    with pytest.raises(ConfigError, match="not valid YAML"):
        hercs.load_config(run)
    assert not marker.exists()


def test_a_checkpoint_of_plain_data_in_the_wrong_shape_is_refused_not_a_traceback(
        run: Path) -> None:
    """Data the safe reader lets through can still be hostile: a number where the policy's
    bytes go would make `bytes(n)` allocate n bytes."""
    best = RunDir(run).checkpoint("best")
    torch.save({"policy": 1 << 40, "epoch": 1}, best)
    with pytest.raises(CheckpointError, match="'policy' is of type int, not the Weights message's"):
        hercs.load_policy(run)
    torch.save({"learner": {"actor": "weights"}, "loop": {"epoch": 1}}, best)
    with pytest.raises(HercsError, match="does not hold what a checkpoint of this version"):
        hercs.load_policy(run)
