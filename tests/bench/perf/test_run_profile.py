"""bench/perf/run_profile: py-spy's raw stacks parsed and grouped (pure), and the quick mode's
real profile of a 1-epoch run, where every process's CPU time is split into groups that add up
to it."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from bench.perf.run_profile.stacks import group_of, group_shares, parse_raw, role_of
from tests.integration.launcher_standins import process_alive

REPO = Path(__file__).resolve().parents[3]
UP = 'process 10:"python -m hercs.apps.cli up --task push"'
LEARNER = f'{UP};process 11:"python -m hercs.apps.cli learner --config c.yaml"'
ACTOR = f'{UP};process 12:"python -m hercs.apps.cli actor --config c.yaml --id actor-3"'
RAW = [
    f"{LEARNER};step (hercs/learner/loop.py:120);update (hercs/learner/ddpg.py:140);"
    "forward (torch/nn/modules/linear.py:134) 7",
    f"{LEARNER};update (hercs/learner/ddpg.py:160);step (torch/optim/adam.py:200);"
    "at::native::_fused_adam_kernel_cpu_ (libtorch_cpu.so) 2",
    f"{LEARNER};update (hercs/learner/ddpg.py:150);clamp_min (libtorch_cpu.so) 1",
    f"{LEARNER};run (threading.py:982);park_timeout (zenoh/zenoh.abi3.so) 40",
    f"{ACTOR};step (gymnasium_robotics/envs/robot_env.py:341);mj_step (libmujoco.so) 5",
    f"{ACTOR};act (hercs/rl/policy.py:91);forward (torch/nn/modules/linear.py:134) 3",
    f"{UP};main (hercs/apps/cli/main.py:10) 1",
    "no process frame 3",
    "",
]


def test_samples_are_split_by_process_with_waits_counted_idle() -> None:
    processes = parse_raw(RAW)
    assert {pid: p.role for pid, p in processes.items()} == {11: "learner", 12: "actor-3",
                                                             10: "up"}
    assert (processes[11].busy, processes[11].idle) == (10, 40)
    assert processes[12].busy == 8


def test_each_stack_lands_in_its_function_group() -> None:
    learner = parse_raw(RAW)[11]
    assert group_shares(learner) == pytest.approx({"GEMMs": 0.7, "Adam": 0.2,
                                                   "rest of the update": 0.1})
    actor = parse_raw(RAW)[12]
    # a Linear's forward in the actor is its policy, not a learner GEMM
    assert group_shares(actor) == pytest.approx({"env stepping": 5 / 8,
                                                 "policy inference (actor)": 3 / 8})
    assert group_of("evaluator-0", "run (hercs/actors/evaluator.py:1)") == "evaluation"
    assert group_of("clusterer", "fit (sklearn/cluster/_kmeans.py:1)") == "clustering"
    assert role_of("python -m hercs.apps.cli evaluator --config c --id evaluator-1") == \
        "evaluator-1"
    assert role_of("py-spy record") == "other"


@pytest.mark.full
def test_quick_mode_splits_every_process_of_a_real_run(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.run_profile", "--quick", "--out",
                           str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    summary = json.loads((tmp_path / "run_profile.json").read_text())
    by_process = summary["cpu_s_per_epoch_by_process"]
    assert set(by_process) == {"up", "replay", "learner", "actor-0", "evaluator-0", "clusterer"}
    assert all(seconds > 0 for seconds in by_process.values())
    groups = summary["cpu_s_per_epoch_by_group"]
    for role, seconds in by_process.items():  # the groups split each process's CPU time
        assert sum(row.get(role, 0.0) for row in groups.values()) == pytest.approx(seconds)
    assert groups["GEMMs"]["learner"] > 0 and groups["env stepping"]["actor-0"] > 0
    with (tmp_path / "run_profile_cores.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert rows and all(0.0 <= float(v) <= 1.0 for r in rows for k, v in r.items()
                        if k.endswith("_busy"))
    text = (tmp_path / "run_profile.md").read_text()
    assert "| learner |" in text and "| GEMMs |" in text


# A stand-in for py-spy, run as a real process: FAKE_PLAN says what each try does. "segv"
# leaves a process behind and dies of SIGSEGV, as py-spy does when it crashes attaching to a new
# process (its run is orphaned); "fail" exits 1; "ok" writes a run folder and a raw stack.
FAKE_PROFILER = '''#!{python}
import os, pathlib, signal, subprocess, sys
argv = sys.argv[1:]
output = pathlib.Path(argv[argv.index("--output") + 1])
command = argv[argv.index("--") + 1:]
runs = pathlib.Path(command[command.index("--run-dir") + 1])
tries = pathlib.Path(os.environ["FAKE_TRIES"])
n = int(tries.read_text()) + 1 if tries.exists() else 1
tries.write_text(str(n))
plan = os.environ["FAKE_PLAN"].split(",")[n - 1]
if plan == "segv":
    left = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    with open(os.environ["FAKE_LEFT"], "a") as f:
        f.write(f"{{left.pid}}\\n")
    os.kill(os.getpid(), signal.SIGSEGV)
if plan == "fail":
    sys.exit(1)
(runs / "reach-x").mkdir(parents=True)
(runs / "reach-x" / "metrics.csv").write_text("epoch,wall_s\\n1,2.5\\n")
output.write_text('process 10:"python -m hercs.apps.cli up --task reach" 1\\n')
'''


def _profile_with(plan: str, tmp_path: Path,
                  monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    import argparse

    from bench.perf.run_profile import __main__ as run_profile

    fake = tmp_path / "fake-py-spy"
    fake.write_text(FAKE_PROFILER.format(python=sys.executable))
    fake.chmod(0o755)
    monkeypatch.setattr(run_profile, "py_spy", lambda: str(fake))
    monkeypatch.setenv("FAKE_PLAN", plan)
    monkeypatch.setenv("FAKE_TRIES", str(tmp_path / "tries"))
    monkeypatch.setenv("FAKE_LEFT", str(tmp_path / "left"))
    (tmp_path / "work").mkdir()
    args = argparse.Namespace(task="reach", method="her-cs", epochs=1, rate=50, set=[])
    return run_profile.profile_run(args, tmp_path / "work")


def _left_behind(tmp_path: Path) -> list[int]:
    return [int(line) for line in (tmp_path / "left").read_text().split()]


def test_a_profiler_that_crashes_is_tried_again_and_its_orphaned_run_stopped(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    measured = _profile_with("segv,ok", tmp_path, monkeypatch)
    assert measured["profiler_crashes"] == ["SIGSEGV"] and measured["epochs"] == 1
    assert (tmp_path / "tries").read_text() == "2"
    left = _left_behind(tmp_path)
    assert len(left) == 1 and not any(process_alive(pid) for pid in left)


def test_a_profiler_that_keeps_crashing_stops_after_its_tries_and_leaves_nothing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from bench.perf.run_profile.__main__ import PROFILER_TRIES

    with pytest.raises(SystemExit, match=rf"exit -11, try {PROFILER_TRIES} of {PROFILER_TRIES}"):
        _profile_with(",".join(["segv"] * PROFILER_TRIES), tmp_path, monkeypatch)
    left = _left_behind(tmp_path)
    assert len(left) == PROFILER_TRIES and not any(process_alive(pid) for pid in left)


def test_a_run_that_fails_on_its_own_is_not_tried_again(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(SystemExit, match=r"exit 1, try 1 of "):
        _profile_with("fail,ok", tmp_path, monkeypatch)
    assert (tmp_path / "tries").read_text() == "1"
