"""A run survives a process dying, and resumes after every process died: real `hercs up`
runs of FetchReach (tiny epochs) with real services, killed with SIGKILL.

Every wait is on a launcher output line, a file's contents or a process exit, with a timeout.
"""

from __future__ import annotations

import contextlib
import csv
import os
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hercs.run.rundir import RunDir
from hercs.run.runlog.reader import read_episode_messages
from tests.integration.launcher_standins import Launcher, process_alive
from tests.support import free_endpoint

pytestmark = pytest.mark.integration

EPOCHS = 4
RUN_S = 240.0


def up_argv(tmp_path: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach",
            "--epochs", str(EPOCHS), "--actors", "2", "--run-dir", str(tmp_path / "runs"),
            "--listen", free_endpoint(),
            "--set", "training.cycles_per_epoch=3", "--set", "training.eval_episodes=2",
            "--set", "launch.restart_backoff_s=0.2", *extra]


def epochs_recorded(run_dir: Path) -> list[int]:
    with RunDir(run_dir).metrics.open(newline="") as f:
        return [int(row["epoch"]) for row in csv.DictReader(f)]


def log_text(run_dir: Path, ident: str) -> str:
    return (RunDir(run_dir).log(ident)).read_text(errors="replace")


def lag_never_negative(run_dir: Path, bound: int | None = None) -> None:
    """Every epoch's recorded policy lag (mean, p50, max) is >= 0, and with `bound` its p50
    is within it: the schedule a restart continues is the one the episodes were stored in
    (before the fix, a resumed run read -6.5 every epoch after the resume)."""
    with RunDir(run_dir).metrics.open(newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["policy_lag_p50"] not in ("", "nan")]
    assert rows, "no epoch recorded a lag"
    for r in rows:
        lags = [float(r[k]) for k in ("policy_lag", "policy_lag_p50", "policy_lag_max")]
        assert min(lags) >= 0, f"epoch {r['epoch']}: negative policy lag {lags}"
        if bound is not None:
            assert lags[1] <= bound, f"epoch {r['epoch']}: lag p50 {lags[1]} past {bound}"


def kill_and_finish(launcher: Launcher, ident: str = "learner-0") -> None:
    """SIGKILL service `ident`, wait for its restart, then for the run to end with status 0."""
    os.kill(launcher.child_pids[ident], signal.SIGKILL)
    role = ident.split("-")[0]
    launcher.wait_for_line(rf"started {role} {ident} again \(restart 1\)", timeout_s=60)
    assert launcher.finish(timeout_s=RUN_S) == 0, "\n".join(launcher.out + launcher.err)


def run_killing_after_epoch_1(tmp_path: Path, run: str, ident: str, *extra: str) -> Path:
    """A run whose service `ident` is SIGKILLed after epoch 1 (`kill_and_finish`); its folder,
    checked to hold every epoch once."""
    launcher = Launcher(up_argv(tmp_path, "--run", run, *extra), cwd=tmp_path)
    try:
        launcher.wait_for_line(r"^epoch 1/4  success", timeout_s=RUN_S)
        kill_and_finish(launcher, ident)
    finally:
        launcher.kill()
    run_dir = tmp_path / "runs" / run
    assert epochs_recorded(run_dir) == [1, 2, 3, 4]
    return run_dir


@pytest.mark.full
def test_a_killed_learner_is_restarted_and_resumes_from_its_checkpoint(tmp_path: Path) -> None:
    launcher = Launcher(up_argv(tmp_path, "--run", "bumpy"), cwd=tmp_path)
    run_dir = tmp_path / "runs" / "bumpy"
    try:
        launcher.wait_for_line(r"^epoch 2/4  success", timeout_s=RUN_S)
        kill_and_finish(launcher)
    finally:
        launcher.kill()
    assert epochs_recorded(run_dir) == [1, 2, 3, 4], "no epoch missing, none twice"
    lag_never_negative(run_dir)
    learner_log = log_text(run_dir, "learner-0")
    assert "resumed from the checkpoint of epoch" in learner_log
    report = "\n".join(launcher.err)
    assert "learner learner-0 exited unexpectedly (killed by SIGKILL); restarting it" in report
    assert any(line.startswith("epoch 4/4") and line.endswith("restarts 1")
               for line in launcher.out), launcher.out
    assert not [i for i, pid in launcher.child_pids.items() if process_alive(pid)]


@pytest.mark.full
def test_a_killed_replay_keeps_the_lag_its_episodes_were_stored_with(tmp_path: Path) -> None:
    """SIGKILL of the replay in epoch 2 of an asynchronous run: the restarted replay recovers
    its log and measures every later episode in the same schedule, so no epoch reads a
    negative lag, and the lag bound holds from its first insert on."""
    run_dir = run_killing_after_epoch_1(tmp_path, "amnesia", "replay-0")
    assert "recovered" in log_text(run_dir, "replay-0")
    lag_never_negative(run_dir, bound=3)


def wait_for_episodes(run_dir: Path, count: int, *, timeout_s: float) -> bool:
    """Until the episode log holds `count` episodes (a segment still being written may end in
    a partial chunk: read again)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if sum(1 for _ in read_episode_messages(run_dir)) >= count:
                return True
        except Exception:  # a chunk still being written: the next read sees it
            pass
        time.sleep(0.2)
    return False


@pytest.mark.full
def test_a_killed_learner_under_a_tight_lag_bound_does_not_hold_the_actors_back(
        tmp_path: Path) -> None:
    """`training.max_policy_lag=1`: the restarted learner broadcasts versions below those the
    acks before its death asked for; the actors must not wait for those numbers (nor the
    replay refuse everything) while the learner waits for their episodes."""
    launcher = Launcher(up_argv(tmp_path, "--run", "tight", "--set", "training.max_policy_lag=1",
                                "--set", "training.cycles_per_epoch=16"), cwd=tmp_path)
    run_dir = tmp_path / "runs" / "tight"
    try:
        # kill it 5 cycles past its checkpoint of epoch 1 (cycle 16): more than the limiter's
        # window and the bound together, so that the restarted learner needs new episodes
        # before it is back at the versions the actors were last told to act with; and 11
        # cycles short of epoch 2's checkpoint (cycle 32), which a learner ahead of the
        # episodes polled here by its window and the bound does not reach, however many
        # cycles a fast machine runs while the log is polled and read (with 8 cycles an
        # epoch the margin was 3)
        launcher.wait_for_line(r"^epoch 1/4", timeout_s=RUN_S)
        assert wait_for_episodes(run_dir, 4 * (16 + 5), timeout_s=RUN_S)
        kill_and_finish(launcher)
    finally:
        launcher.kill()
    assert epochs_recorded(run_dir) == [1, 2, 3, 4], "no epoch missing, none twice"
    assert "resumed from the checkpoint of epoch 1" in log_text(run_dir, "learner-0")


@pytest.mark.full
def test_a_killed_actor_comes_back_under_a_new_incarnation(tmp_path: Path) -> None:
    """The run's only actor (the last --actors wins): the run cannot end on another actor's
    episodes before the killed one is back, so its new incarnation always inserts."""
    run_dir = run_killing_after_epoch_1(tmp_path, "actorless", "actor-0", "--actors", "1")
    wire_ids = [line.split("wire id ")[1].split(")")[0]
                for line in log_text(run_dir, "actor-0").splitlines() if "wire id" in line]
    assert len(wire_ids) == 2 and wire_ids[0] != wire_ids[1], wire_ids
    assert all(i.startswith("actor-0@") for i in wire_ids)


@pytest.mark.full
def test_a_run_whose_processes_all_died_resumes_to_the_same_epoch_count(tmp_path: Path) -> None:
    """SIGKILL of the launcher kills every child (PR_SET_PDEATHSIG): nothing is left
    running. `hercs up --resume` then finishes the run: every epoch recorded once, the
    replay's episodes recovered from the log."""
    run_dir = tmp_path / "runs" / "phoenix"
    first = Launcher(up_argv(tmp_path, "--run", "phoenix"), cwd=tmp_path)
    try:
        first.wait_for_line(r"^epoch 2/4  success", timeout_s=RUN_S)
        pids = first.child_pids
        first.proc.kill()
        first.proc.wait()
        assert _wait_all_gone(pids.values()), "children outlived the launcher"
    finally:
        first.kill()
    recorded_before = epochs_recorded(run_dir)
    assert recorded_before[:2] == [1, 2]

    again = Launcher([sys.executable, "-m", "hercs.apps.cli", "up", "--resume", str(run_dir),
                      "--listen", free_endpoint()], cwd=tmp_path)
    try:
        assert again.finish(timeout_s=RUN_S) == 0, "\n".join(again.out + again.err)
    finally:
        again.kill()
    assert epochs_recorded(run_dir) == [1, 2, 3, 4]
    lag_never_negative(run_dir, bound=3)  # training.max_policy_lag's default
    assert any("resuming run phoenix" in line for line in again.out)
    replay_log = log_text(run_dir, "replay-0")
    assert "recovered" in replay_log and "acked episodes from the episode log" in replay_log
    assert "resumed from the checkpoint of epoch" in log_text(run_dir, "learner-0")


def _wait_all_gone(pids, timeout_s: float = 20.0) -> bool:
    """True once none of `pids` runs (they are the launcher's children: poll /proc)."""
    deadline = time.monotonic() + timeout_s
    while any(process_alive(pid) for pid in pids):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


@pytest.mark.full
def test_lockstep_survives_a_killed_replay_and_learner_without_breaking_its_schedule(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`training.schedule=lockstep`, HER-CS, two actors: SIGKILL the replay during epoch 2
    and the learner during epoch 3. The replay rebuilds its per-version counts from its log,
    the learner trains the cycles since its checkpoint again on the episodes stored for them,
    and the episode log still holds, episode for episode, the reference's schedule: episode i
    acted with weights version i // 4."""
    monkeypatch.setenv("HERCS_LOG", "DEBUG")  # what a failure prints is what CI keeps
    launcher = Launcher(up_argv(tmp_path, "--run", "strict", "--method", "her-cs",
                                "--set", "training.schedule=lockstep",
                                "--set", "cluster.k=2", "--set", "cluster.fgb_size=8"),
                        cwd=tmp_path)
    run_dir = tmp_path / "runs" / "strict"
    try:
        with service_logs_on_failure(run_dir):
            _kill_replay_then_learner(launcher)
    finally:
        launcher.kill()
    assert epochs_recorded(run_dir) == [1, 2, 3, 4]
    logged = list(read_episode_messages(run_dir))
    assert [episode_id for episode_id, _ in logged] == list(range(len(logged)))
    versions = [int(msg.policy_version) for _, msg in logged]
    assert versions == [i // 4 for i in range(len(logged))], versions
    with RunDir(run_dir).metrics.open(newline="") as f:
        assert {float(row["policy_lag"]) for row in csv.DictReader(f)} == {0.0}
    assert "recovered" in log_text(run_dir, "replay-0")
    assert "resumed from the checkpoint of epoch" in log_text(run_dir, "learner-0")


def _kill_replay_then_learner(launcher: Launcher) -> None:
    launcher.wait_for_line(r"^epoch 1/4  success", timeout_s=RUN_S)
    os.kill(launcher.child_pids["replay-0"], signal.SIGKILL)
    launcher.wait_for_line(r"started replay replay-0 again \(restart 1\)", timeout_s=60)
    launcher.wait_for_line(r"^epoch 2/4  success", timeout_s=RUN_S)
    os.kill(launcher.child_pids["learner-0"], signal.SIGKILL)
    launcher.wait_for_line(r"started learner learner-0 again \(restart 1\)", timeout_s=60)
    assert launcher.finish(timeout_s=RUN_S) == 0, "\n".join(launcher.out + launcher.err)


@contextlib.contextmanager
def service_logs_on_failure(run_dir: Path, lines: int = 40) -> Iterator[None]:
    """On a failed assertion, add the end of every service's log to its message: CI keeps
    only its output, and a stall (this test once waited 4 min after the replay restart, with
    nothing at INFO) needs each process's last words to be explained."""
    try:
        yield
    except AssertionError as exc:
        tails = []
        for log in sorted(RunDir(run_dir).logs.glob("*.log")):
            text = log.read_text(errors="replace").splitlines()[-lines:]
            tails.append(f"--- {log.name} (last {len(text)} lines)\n" + "\n".join(text))
        raise AssertionError(f"{exc}\n\n" + "\n".join(tails)) from exc


def metrics_rows(run_dir: Path) -> list[dict[str, str]]:
    with RunDir(run_dir).metrics.open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.full
def test_a_learner_killed_mid_epoch_changes_only_the_wall_time(tmp_path: Path) -> None:
    """The learner dies half-way through epoch 2, long after its checkpoint of epoch 1; the
    updates it loses are redone on the episodes already stored (the limiter follows its kept
    count: SampleRequest.samples_kept), so epochs 2-4 take the env steps per update of a run
    without the fault, within 5 %. Before, the limiter had admitted a fresh episode for every
    update that was undone (chaos2: 27,000 env steps for 2,000 updates in one epoch)."""
    # 16 cycles an epoch: killed at cycle 24, 8 short of epoch 2's checkpoint, a margin a
    # fast machine does not run through while the episode log is polled and read
    cycles, per_cycle, minibatches, horizon = 16, 4, 40, 50
    launcher = Launcher(up_argv(tmp_path, "--run", "midway", "--method", "her",
                                "--set", f"training.cycles_per_epoch={cycles}"), cwd=tmp_path)
    run_dir = tmp_path / "runs" / "midway"
    try:
        launcher.wait_for_line(r"^epoch 1/4  success", timeout_s=RUN_S)
        first = int(metrics_rows(run_dir)[0]["episodes"])
        # half of epoch 2's episodes stored: the learner is mid-epoch, its checkpoint behind
        assert wait_for_episodes(run_dir, first + cycles * per_cycle // 2, timeout_s=RUN_S)
        kill_and_finish(launcher)
    finally:
        launcher.kill()
    rows = metrics_rows(run_dir)
    assert [int(r["epoch"]) for r in rows] == [1, 2, 3, 4]
    steps = [int(r["env_steps"]) for r in rows]
    updates = [int(r["updates"]) for r in rows]
    nominal = per_cycle * horizon / minibatches  # env steps per update without a fault
    after = (steps[-1] - steps[0]) / (updates[-1] - updates[0])
    per_epoch = [(s1 - s0) / (u1 - u0) for s0, s1, u0, u1
                 in zip(steps, steps[1:], updates, updates[1:], strict=False)]
    print(f"env steps per update, epochs 2-4: {after:.3f} (nominal {nominal:g}); per epoch "
          f"{[round(x, 3) for x in per_epoch]}")
    assert "resumed from the checkpoint of epoch 1" in log_text(run_dir, "learner-0")
    assert abs(after / nominal - 1) <= 0.05, (after, nominal, per_epoch)
