"""Runs as Slurm jobs on a real Slurm (tests/integration/minislurm.py): `hercs slurm submit` of
a heterogeneous job, the time-limit warning and requeue with resume, a killed actor step and a
dead node, and `hercs sweep --slurm` as a job array. Skipped, with the reason, where no cluster
can run (`make slurm`). Slurm reports a job's end only when asked, so the waits poll `sacct`.
The test cluster and its timings: docs/CLUSTER.md §8.
"""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hercs.config import load_yaml
from hercs.run.router_record import read_router
from hercs.run.rundir import RunDir
from hercs.run.runlog.reader import read_episode_messages
from tests.integration import minislurm

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.full]

REPO = Path(__file__).resolve().parents[2]
TINY = ("--set", "training.eval_episodes=2", "--set", "ddpg.hidden_size=64")
"""What keeps a run small: 2 test episodes per epoch, small networks."""
POLL_S = 2.0
TERMINAL = {"COMPLETED", "FAILED", "CANCELLED", "TIMEOUT", "NODE_FAIL", "OUT_OF_MEMORY",
            "BOOT_FAIL", "DEADLINE", "PREEMPTED"}


@pytest.fixture(scope="module")
def cluster() -> Iterator[minislurm.MiniSlurm]:
    reason = minislurm.problem()
    if reason is not None:
        print(f"SKIPPED: {reason}")
        pytest.skip(reason)
    slurm = minislurm.MiniSlurm().start()
    try:
        yield slurm
    finally:
        slurm.stop()


@pytest.fixture(autouse=True)
def clean_cluster(cluster: minislurm.MiniSlurm) -> Iterator[None]:
    """Every test gets the cluster as `start()` left it, whatever the test before it did: a
    test that failed with a node down or a job running would otherwise fail the next ones (CI
    once saw a grid task sent to the node a failed test had left without its slurmd)."""
    yield
    cluster.restore()


def env_of(cluster: minislurm.MiniSlurm) -> dict[str, str]:
    """The client commands' environment; sbatch passes it on to the job (PYTHONPATH: this
    checkout's hercs on every node)."""
    return dict(cluster.env, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")


def slurm_submit(cluster: minislurm.MiniSlurm, *flags: str, cwd: Path) -> str:
    """Submit from `cwd` (the test's own folder, as the job's working directory, where a file
    Slurm names by default would land), never from the repository."""
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "slurm", "submit", *flags],
                          capture_output=True, text=True, env=env_of(cluster), cwd=cwd,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    match = re.search(r"job (\d+) runs", done.stdout)
    assert match, done.stdout
    return match.group(1)


def sacct(cluster: minislurm.MiniSlurm, job: str, *extra: str) -> list[dict[str, str]]:
    fields = ["JobID", "JobName", "NodeList", "State", "ExitCode", "Elapsed", "Start", "End"]
    out = subprocess.run(["sacct", "-j", job, "-P", "-n", "-o", ",".join(fields), *extra],
                         capture_output=True, text=True, env=cluster.env, timeout=60,
                         check=True).stdout
    return [dict(zip(fields, line.split("|"), strict=True)) for line in out.splitlines()]


def wait_job(cluster: minislurm.MiniSlurm, job: str, timeout_s: float,
             output: Path | None = None,
             terminal: frozenset[str] | set[str] = TERMINAL) -> list[dict[str, str]]:
    """Until every component of `job` (het components, array tasks) has ended for good
    (a requeued job goes back to PENDING; `terminal` may leave out a state that Slurm follows
    with a requeue); its sacct lines."""
    deadline = time.monotonic() + timeout_s
    while True:
        rows = [r for r in sacct(cluster, job, "-X") if r["JobID"].split(".")[0]]
        states = {r["State"].split()[0] for r in rows}
        if rows and states <= terminal:
            return sacct(cluster, job)
        if time.monotonic() > deadline:
            tail = output.read_text()[-4000:] if output and output.exists() else ""
            raise AssertionError(f"job {job} not done after {timeout_s} s: {rows}\n{tail}\n"
                                 f"{cluster.logs()}")
        time.sleep(POLL_S)


def metrics_epochs(run_dir: Path) -> list[int]:
    with RunDir(run_dir).metrics.open() as f:
        return [int(row["epoch"]) for row in csv.DictReader(f)]


def test_a_run_as_a_heterogeneous_job_puts_its_actor_on_the_second_host_over_tls(
        cluster: minislurm.MiniSlurm, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    job = slurm_submit(cluster, "--task", "reach", "--method", "her-cs", "--epochs", "2",
                       "--run", "het", "--run-dir", str(runs), "--actor-nodes", "1",
                       "--actor-cpus", "1", "--learner-cpus", "1",
                       "--set", "training.cycles_per_epoch=3", *TINY, cwd=tmp_path)
    run_dir = runs / "het"
    output = RunDir(run_dir).slurm / f"job-{job}.out"
    rows = wait_job(cluster, job, timeout_s=300, output=output)
    text = output.read_text()
    print(f"sacct of job {job}:\n" + "\n".join("|".join(r.values()) for r in rows))

    assert metrics_epochs(run_dir) == [1, 2], text
    # component 0: the allocation, the batch script and `hercs up`'s step on hercs-n1;
    # component 1: the allocation and the actors' step on hercs-n2 (step numbers follow
    # the order the two srun calls registered in); every one ended with exit code 0
    placed = sorted((r["JobID"].partition("+")[2].partition(".")[0],
                     re.sub(r"^\d+$", "step", r["JobID"].partition(".")[2]) or "job",
                     r["NodeList"], r["State"], r["ExitCode"]) for r in rows)
    assert placed == [("0", "batch", "hercs-n1", "COMPLETED", "0:0"),
                      ("0", "job", "hercs-n1", "COMPLETED", "0:0"),
                      ("0", "step", "hercs-n1", "COMPLETED", "0:0"),
                      ("1", "job", "hercs-n2", "COMPLETED", "0:0"),
                      ("1", "step", "hercs-n2", "COMPLETED", "0:0")], text
    # every episode came from the actor on hercs-n2, which reached the router by its name
    # over mutual TLS with this attempt's certificates
    actors = {e.actor_id.partition("@")[0] for _, e in read_episode_messages(run_dir)}
    assert actors and all(a.startswith("hercs-n2-") for a in actors), actors
    assert re.search(r"remote actor hercs-n2-\S+ joined", text), text
    config = load_yaml(RunDir(run_dir).config)
    assert config.transport.listen == ["tls/0.0.0.0:0"]
    assert config.security.tls_ca == str(RunDir(run_dir).slurm / f"certs-{job}.0" / "ca.pem")
    assert not (RunDir(run_dir).slurm / f"certs-{job}.0" / "ca.key").exists()
    assert config.actor.num_actors == 0 and config.actor.envs_per_process == 1
    assert read_router(run_dir) is None  # removed when the run stopped


def wait_for_epoch(run_dir: Path, epoch: int, timeout_s: float,
                   poll_s: float = POLL_S) -> None:
    """Until `metrics.csv` holds `epoch` (a file another process writes: polled)."""
    deadline = time.monotonic() + timeout_s
    while not (RunDir(run_dir).metrics.is_file() and epoch in metrics_epochs(run_dir)):
        assert time.monotonic() < deadline, f"no epoch {epoch} within {timeout_s:g} s"
        time.sleep(poll_s)


def submit_reach(cluster: minislurm.MiniSlurm, runs: Path, run: str, *, epochs: int,
                 time_limit: str, extra: tuple[str, ...] = ()) -> tuple[str, Path, Path]:
    """A small FetchReach HER job (one actor node, 5 cycles per epoch): its id, run folder
    and job output file."""
    job = slurm_submit(cluster, "--task", "reach", "--method", "her", "--epochs", str(epochs),
                       "--run", run, "--run-dir", str(runs), "--actor-nodes", "1",
                       "--actor-cpus", "1", "--learner-cpus", "1", "--time", time_limit,
                       *extra, "--set", "training.cycles_per_epoch=5", *TINY,
                       cwd=runs.parent)
    run_dir = runs / run
    return job, run_dir, RunDir(run_dir).slurm / f"job-{job}.out"


def test_a_run_warned_of_its_time_limit_requeues_and_resumes_to_the_end(
        cluster: minislurm.MiniSlurm, tmp_path: Path) -> None:
    """Slurm's warning before the time limit (`--signal=B:USR1@S`: USR1 to the batch shell
    alone) is sent by the test once epoch 1 of 8 is recorded, with
    `scancel --batch --signal=USR1`, so the attempt is cut short on a machine of any speed:
    the run stops in order, the job requeues itself, and the next attempt resumes it to the
    end. (That Slurm sends the warning at the limit was measured on this cluster: 60 s into
    a 2-minute attempt with --signal-before 30, docs/CLUSTER.md §4.)"""
    runs = tmp_path / "runs"
    job, run_dir, output = submit_reach(cluster, runs, "long", epochs=8, time_limit="30",
                                        extra=("--signal-before", "30"))
    wait_for_epoch(run_dir, 1, timeout_s=600, poll_s=0.2)  # 7 epochs still to go
    subprocess.run(["scancel", "--batch", "--signal=USR1", job], env=cluster.env, timeout=60,
                   check=True)
    wait_job(cluster, job, timeout_s=900, output=output)
    text = output.read_text()
    attempts = sacct(cluster, job, "-X", "--duplicates")
    print(f"attempts of job {job}:\n" + "\n".join("|".join(r.values()) for r in attempts))

    assert text.count("got SIGUSR1, stopping the run in order") == 1, text
    assert text.count("requeueing: the next attempt continues the run") == 1, text
    assert text.count("continuing run long (hercs up --resume)") == 1, text
    assert metrics_epochs(run_dir) == list(range(1, 9)), text
    final = [r for r in attempts if r["JobID"] == f"{job}+0"]
    assert final[-1]["State"] == "COMPLETED", attempts
    assert len(final) == 2, attempts  # one accounting record per attempt


def _actor_pids(run: str) -> list[int]:
    """The `hercs actor --run RUN` processes on this machine (the nodes share its pids)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                argv = (entry / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            # the actor itself, not the `srun` that started it (whose argv names it too)
            if (b"hercs.apps.cli" in argv and b"actor" in argv and run.encode() in argv
                    and not argv[0].endswith(b"srun")):
                pids.append(int(entry.name))
    return pids


def test_a_killed_actor_step_is_started_again_within_the_attempt(
        cluster: minislurm.MiniSlurm, tmp_path: Path) -> None:
    """The actor on hercs-n2 is SIGKILLed after epoch 1: the job script starts its step again
    within the attempt (before: training stalled until the time-limit warning requeued the
    job, 1 min 48 s measured). The actors are the run's only source of episodes, so every
    later epoch is the restarted step's work."""
    runs = tmp_path / "runs"
    job, run_dir, output = submit_reach(cluster, runs, "bumpy", epochs=4, time_limit="15")
    # polled often: the kill must come while the run has epochs to go, on a fast machine too
    wait_for_epoch(run_dir, 1, timeout_s=600, poll_s=0.2)
    pids = _actor_pids("bumpy")
    assert len(pids) == 1, f"one actor process, not its srun: {pids}"
    os.kill(pids[0], signal.SIGKILL)  # the task only: srun sees it die
    killed = time.monotonic()
    while not [p for p in _actor_pids("bumpy") if p not in pids]:
        assert time.monotonic() - killed < 120, output.read_text()
        time.sleep(0.2)  # processes Slurm starts: polled
    restarted_after_s = time.monotonic() - killed
    print(f"a new actor process {restarted_after_s:.1f} s after the kill")
    wait_job(cluster, job, timeout_s=600, output=output)
    text = output.read_text()
    assert text.count("the actor step ended with status") == 1, text
    assert restarted_after_s < 60.0, text
    assert "requeueing" not in text, "the attempt went on"
    assert metrics_epochs(run_dir) == [1, 2, 3, 4], text
    final = [r for r in sacct(cluster, job, "-X") if r["JobID"] == f"{job}+0"]
    assert final[-1]["State"] == "COMPLETED", final


def test_a_node_that_dies_fails_the_job_which_requeues_and_resumes(
        cluster: minislurm.MiniSlurm, tmp_path: Path) -> None:
    """hercs-n2 (the actor's node) dies after epoch 2 of 8: every process on it is
    SIGKILLed. slurmctld marks it down after SlurmdTimeout (60 s here), ends the job NODE_FAIL
    and, as the script asks `--requeue`, requeues it; once the node is back the next attempt
    resumes the run from its checkpoint, and every epoch is in metrics.csv once.

    The node dies while the run has 6 epochs to go (metrics.csv polled every 0.2 s): before,
    with 2 of 4 to go and a poll every 2 s, a fast CI machine finished the run first and the
    node died with nothing but its slurmd on it."""
    runs = tmp_path / "runs"
    job, run_dir, output = submit_reach(cluster, runs, "nodefail", epochs=8, time_limit="30")
    wait_for_epoch(run_dir, 2, timeout_s=600, poll_s=0.2)
    actor = _actor_pids("nodefail")
    killed = cluster.take_down("hercs-n2")
    down_at = time.monotonic()
    print(f"epochs {metrics_epochs(run_dir)} recorded when hercs-n2 died; its processes "
          f"{killed}, the actor {actor}")
    assert len(actor) == 1 and actor[0] in killed, f"the actor {actor} died with the node"
    assert len(killed) >= 3, "slurmd, the step's slurmstepd and the actor at least"
    while not cluster.node_state("hercs-n2").startswith("down"):
        assert time.monotonic() - down_at < 300, cluster.logs()
        time.sleep(POLL_S)  # slurmctld's view, only told by asking
    detected_s = time.monotonic() - down_at
    cluster.bring_up("hercs-n2")
    # NODE_FAIL is followed by the requeue (a moment later): wait past it
    wait_job(cluster, job, timeout_s=900, output=output, terminal=TERMINAL - {"NODE_FAIL"})
    attempts = sacct(cluster, job, "-X", "--duplicates")
    print(f"node down seen after {detected_s:.0f} s; attempts of job {job}:\n"
          + "\n".join("|".join(r.values()) for r in attempts))
    text = output.read_text()
    states = [r["State"].split()[0] for r in attempts if r["JobID"] == f"{job}+0"]
    assert "NODE_FAIL" in states and states[-1] == "COMPLETED", attempts
    assert text.count("continuing run nodefail (hercs up --resume)") >= 1, text
    assert metrics_epochs(run_dir) == list(range(1, 9)), text


def test_the_grid_as_a_job_array_runs_one_cell_per_task(cluster: minislurm.MiniSlurm,
                                                        tmp_path: Path) -> None:
    runs, committed = tmp_path / "grid", tmp_path / "committed"
    done = subprocess.run(
        [sys.executable, "-m", "hercs.apps.cli", "sweep", "--slurm", "--tasks", "reach",
         "--methods", "her", "her-cs", "--seeds", "1", "--epochs", "1", "--run-dir", str(runs),
         "--committed", str(committed), "--slurm-cpus", "1", "--slurm-time", "10",
         *(item for o in ("training.cycles_per_epoch=2", "training.eval_episodes=2",
                          "ddpg.hidden_size=64") for item in ("--set", o))],
        capture_output=True, text=True, env=env_of(cluster), cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    match = re.search(r"array job (\d+)", done.stdout)
    assert match, done.stdout
    job = match.group(1)
    rows = wait_job(cluster, job, timeout_s=600)
    tasks = {r["JobID"]: r for r in rows if re.fullmatch(rf"{job}_\d+", r["JobID"])}
    assert {k: r["State"] for k, r in tasks.items()} == {f"{job}_0": "COMPLETED",
                                                         f"{job}_1": "COMPLETED"}, rows
    for name in ("reach-her-s1", "reach-her-cs-s1"):
        assert metrics_epochs(runs / name) == [1], name
        assert (committed / name / "bench_done.json").is_file(), name
    manifest = json.loads((runs / "sweep.json").read_text())
    assert [c["state"] for c in manifest["cells"]] == ["done", "done"], manifest
    assert os.path.isdir(runs)
