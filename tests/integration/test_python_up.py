"""`hercs.up(...)`, the Python API's launcher, from a fresh interpreter as a user's script or
notebook runs it: a real FetchReach run (router, replay, clusterer, learner, evaluator, an
actor) whose rows arrive as epochs end, whose orderly stop keeps what it made and resumes to
the end, and which never outlives the interpreter that started it."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import hercs
from hercs.apps.launch.resume_check import CannotResume
from hercs.apps.launch.run_lock import RunLock
from hercs.errors import ConfigError, HercsError
from hercs.run.rundir import RunDir, RunDirError
from tests.run_dirs import make_run

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
SCRIPT_TIMEOUT_S = 600
SMALL = {"training.cycles_per_epoch": 2, "training.eval_episodes": 2}


def _python(tmp_path: Path, code: str) -> dict:
    """Run `code` in a fresh interpreter in tmp_path; its last stdout line is JSON."""
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=SCRIPT_TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def _processes_naming(text: str) -> list[str]:
    """Command lines of live processes that contain `text`."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            args = cmdline.read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in args:
            found.append(args)
    return found


def _state(pid: int) -> str:
    """A process's state letter (R, S, Z, ...), or "gone"."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return "gone"
    return status.split("State:")[1].split()[0]


@pytest.mark.full
def test_a_run_started_from_python_yields_its_rows_and_its_policy(tmp_path: Path) -> None:
    out = _python(tmp_path, f"""
import json, numpy as np, hercs
run = hercs.up(task="reach", method="her-cs", epochs=3, seed=1, run_dir="runs",
               overrides={SMALL!r})
epochs = [row["epoch"] for row in run.rows(timeout_s=300)]
code = run.wait()
policy = run.policy("best")
obs = {{"observation": np.zeros(10), "desired_goal": np.zeros(3)}}
transport = hercs.load_config(run.dir).transport
print(json.dumps({{"epochs": epochs, "code": code, "dir": str(run.dir), "name": run.name,
                  "metrics": len(run.metrics), "action": list(policy.act(obs).shape),
                  "last": run.output[-1], "listen": transport.listen,
                  "connect": transport.connect}}))
""")
    assert out["epochs"] == [1, 2, 3]
    assert out["code"] == 0 and out["metrics"] == 3 and out["action"] == [4]
    assert Path(out["dir"]) == tmp_path / "runs" / out["name"]
    assert out["name"].startswith("reach-her-cs-s1-")
    assert out["last"].endswith(f"finished; run directory: runs/{out['name']}; its episodes: "
                                f"hercs view runs/{out['name']}")
    assert RunDir(Path(out["dir"])).config.is_file()
    # no listen=: a free port of loopback (docs/python_api.md), the one its services used
    assert out["listen"] == ["tcp/127.0.0.1:0"]
    [endpoint] = out["connect"]
    assert re.fullmatch(r"tcp/127\.0\.0\.1:\d+", endpoint) and not endpoint.endswith(":0")


@pytest.mark.full
def test_stop_keeps_the_epochs_and_resume_goes_on_to_the_end(tmp_path: Path) -> None:
    # 200 epochs: the stop lands mid-run on any machine (it follows the first row at once)
    out = _python(tmp_path, f"""
import json, hercs
run = hercs.up(task="reach", method="her", epochs=200, seed=2, name="stopme",
               run_dir="runs", overrides={SMALL!r})
first = next(run.rows(timeout_s=300))
stopped = run.stop()
kept = [int(r["epoch"]) for r in run.metrics]
again = run.resume(epochs=kept[-1] + 1)
resumed = again.wait(timeout_s=300)
print(json.dumps({{"first": first["epoch"], "stopped": stopped, "kept": kept,
                  "resumed": resumed, "epochs": [int(r["epoch"]) for r in again.metrics],
                  "same_dir": again.dir == run.dir}}))
""")
    assert out["first"] == 1
    assert out["stopped"] == 130  # hercs up's exit status after SIGINT: 128 + 2
    assert out["kept"] == list(range(1, len(out["kept"]) + 1)) and len(out["kept"]) < 200
    assert out["resumed"] == 0 and out["same_dir"]
    assert out["epochs"] == list(range(1, len(out["kept"]) + 2))  # one more, none twice


def test_a_run_never_outlives_the_interpreter_that_started_it(tmp_path: Path) -> None:
    out = _python(tmp_path, f"""
import json, hercs
run = hercs.up(task="reach", method="her", epochs=200, name="orphan-check",
               run_dir="runs", overrides={SMALL!r})
next(run.rows(timeout_s=300))
print(json.dumps({{"dir": str(run.dir)}}))
# no stop(): the exit hook stops it
""")
    assert _processes_naming(out["dir"]) == []
    assert _processes_naming("--run orphan-check") == []
    assert RunDir(Path(out["dir"])).metrics.is_file()


def test_a_run_stops_in_order_when_its_interpreter_is_killed(tmp_path: Path) -> None:
    """No exit hooks run after SIGKILL: the kernel's parent-death signal (SIGTERM) stops it."""
    script = f"""
import os, signal, hercs
run = hercs.up(task="reach", method="her", epochs=200, name="killed-parent",
               run_dir="runs", overrides={SMALL!r})
next(run.rows(timeout_s=300))
print(run._proc.pid, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True,
                          text=True, timeout=SCRIPT_TIMEOUT_S)
    assert done.returncode == -signal.SIGKILL, done.stdout + done.stderr
    launcher = int(done.stdout.split()[-1])
    deadline = time.monotonic() + 120  # hercs up's orderly stop: stages of a few seconds
    while _processes_naming("killed-parent") and time.monotonic() < deadline:
        time.sleep(0.5)
    assert _processes_naming("killed-parent") == []
    assert _state(launcher) in ("gone", "Z"), _state(launcher)  # exited (a zombie until reaped)
    log = RunDir(tmp_path / "runs" / "killed-parent").log("learner-0").read_text()
    assert "Traceback" not in log  # stopped, not crashed


def test_a_taken_folder_or_a_refused_resume_never_reads_another_runs_files(
        tmp_path: Path) -> None:
    taken = tmp_path / "runs" / "taken"
    taken.mkdir(parents=True)
    RunDir(taken).metrics.write_text("epoch,success_rate\n1,0.5\n")
    with pytest.raises(ConfigError, match=r"already holds a run.*hercs\.resume"):
        hercs.up(task="reach", name="taken", run_dir=str(tmp_path / "runs"))
    with pytest.raises(RunDirError, match=r"it has no config\.yaml"):
        hercs.resume(taken)  # checked before anything starts, as hercs.up checks its input
    # a run whose files pass the check but that another `hercs up` holds: the command refuses
    held = tmp_path / "runs" / "held"
    make_run(held, epochs=3, trained=1, checkpoint=1)
    lock = RunLock.take(held)
    try:
        refused = hercs.resume(held)
        assert refused.wait(timeout_s=120) == 2
    finally:
        lock.release()
    assert any("is in use by a running `hercs up`" in line for line in refused.output)
    assert list(refused.rows(timeout_s=10)) == []
    with pytest.raises(HercsError, match="did not start it"):
        refused.metrics  # noqa: B018 - the property raises
    with pytest.raises(HercsError, match="did not start it"):
        refused.resume()


@pytest.mark.parametrize(("damage", "error", "message"), [
    ("missing", RunDirError, "no such folder"),
    ("no-config", RunDirError, r"it has no config\.yaml"),
    ("bad-config", ConfigError, "not valid YAML"),
    ("bad-checkpoint", CannotResume, "not a readable learner checkpoint"),
    ("bad-epochs", ConfigError, "arguments refused"),
], ids=["missing", "no-config", "bad-config", "bad-checkpoint", "bad-epochs"])
def test_resuming_a_folder_that_cannot_be_resumed_raises_at_once(
        tmp_path: Path, damage: str, error: type[HercsError], message: str) -> None:
    run = tmp_path / "runs" / "r"
    if damage != "missing":
        make_run(run, epochs=3, trained=1, checkpoint=1)
    if damage == "no-config":
        RunDir(run).config.unlink()
    elif damage == "bad-config":
        RunDir(run).config.write_text("ddpg: [\n")
    elif damage == "bad-checkpoint":
        RunDir(run).checkpoint("latest").write_bytes(b"cut short")
    with pytest.raises(error, match=message):
        hercs.resume(run, epochs="many" if damage == "bad-epochs" else None)  # type: ignore[arg-type]
    assert _processes_naming(str(run)) == [], "no `hercs up` was started"


def test_a_bad_value_raises_before_anything_starts(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"ddpg\.lr_actor"):
        hercs.up(task="reach", run_dir=str(tmp_path / "runs"),
                 overrides={"ddpg.lr_actor": "fast"})
    with pytest.raises(ConfigError, match=r"task\.name: got 'no-such-task'"):
        hercs.up(task="no-such-task", run_dir=str(tmp_path / "runs"))
    refused = r"actor\.num_actors: got 'two', must be a number"
    with pytest.raises(ConfigError, match=refused):
        hercs.up(task="reach", actors="two",  # type: ignore[arg-type]
                 run_dir=str(tmp_path / "runs"))
    with pytest.raises(ConfigError, match="not the string"):
        hercs.up(task="reach", run_dir=str(tmp_path / "runs"), overrides="ddpg.lr_actor=1")
    assert not (tmp_path / "runs").exists()


@pytest.mark.full
def test_the_docs_example_runs_as_written(tmp_path: Path) -> None:
    """docs/python_api.md's notebook cell, verbatim: 3 epochs watched, stopped, evaluated."""
    text = (REPO / "docs" / "python_api.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S)
    assert code is not None, "docs/python_api.md has no python block"
    done = subprocess.run([sys.executable, "-c", code.group(1)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=SCRIPT_TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    assert [line.split(":")[0] for line in lines if line.startswith("epoch ")] == [
        "epoch 1", "epoch 2", "epoch 3"]
    assert "stopped with 130" in lines
    assert lines[-2] == f"<hercs.Run api-demo ended (130) in {tmp_path / 'runs' / 'api-demo'}>"
    assert re.fullmatch(r"best policy \(epoch [123]\): success (0|1)\.\d\d over 10 episodes",
                        lines[-1])
