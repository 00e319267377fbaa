"""`hercs up` (hercs.apps.launch.launcher) with the real services: end to end, lockstep runs, the
authors' v1 env.

The pure parts: test_launcher.py; stand-in children: test_launcher_processes.py. Every wait is
on process exit, a launcher output line, a file's contents or a Zenoh event, with a timeout.
"""

from __future__ import annotations

import csv
import re
import sys
from importlib.util import find_spec
from pathlib import Path

import pytest

from hercs.config import load_yaml
from hercs.run.rundir import RunDir
from hercs.run.runlog.reader import read_cluster_models, read_episode_messages
from tests.integration.launcher_standins import Launcher, process_alive
from tests.support import free_endpoint, skip_without_mujoco_py

pytestmark = pytest.mark.integration


SERVICE_MODULES = ("hercs.replay_service.replay_shell", "hercs.clusterer.clusterer_shell",
                   "hercs.learner.learner_shell", "hercs.actors.actor_shell",
                   "hercs.actors.evaluator")


def up_to_the_end(tmp_path: Path, run: str, args: list[str], timeout_s: float,
                  ) -> tuple[Launcher, Path]:
    """Runs `hercs up --task reach --run RUN` with these arguments to its end (exit 0 asserted),
    the process killed whatever happens; the launcher (its output) and the run directory."""
    launcher = Launcher(
        [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--run", run,
         "--run-dir", str(tmp_path / "runs"), "--listen", free_endpoint(), *args],
        cwd=tmp_path,
    )
    try:
        assert launcher.finish(timeout_s=timeout_s) == 0, "\n".join(launcher.out + launcher.err)
    finally:
        launcher.kill()
    return launcher, tmp_path / "runs" / run


@pytest.mark.slow
@pytest.mark.skipif(not all(find_spec(m) for m in SERVICE_MODULES),
                    reason="a service module is not written yet")
def test_up_end_to_end_with_the_real_services(tmp_path: Path) -> None:
    launcher, run_dir = up_to_the_end(tmp_path, "e2e", [
        "--epochs", "2", "--actors", "2", "--set", "training.cycles_per_epoch=2",
        "--set", "training.eval_episodes=2"], timeout_s=90)
    epochs = [line for line in launcher.out
              if line.startswith("epoch") and " running " not in line]
    assert [line.split()[1] for line in epochs] == ["1/2", "2/2"]
    # not a terminal: no live line (test_up_live_line.py has one), one line per epoch
    assert not [line for line in launcher.out if "cycle " in line or "\x1b" in line
                or "\r" in line], launcher.out
    # HER-CS on Reach for 8 cycles: far fewer failed goals than the 150 a model needs
    assert all(re.fullmatch(r"epoch \d/2  success \d\.\d\d  env \d+ steps/s  upd \d+/s  "
                            r"replay \d+  lag [-\d.]+  actors \d+( \([\d/]+ %\))?  "
                            r"clusters none yet( \(\d+/150 failed goals\))?(  eta \S+)?",
                            line)
               for line in epochs), epochs
    why = re.fullmatch(r"hercs up: no cluster model: (\d+) failed goals? in (\d+) episodes, a "
                       r"fit needs cluster\.fgb_size=150.*; a longer run or a smaller --set "
                       r"cluster\.fgb_size=N fits one", launcher.out[-2])
    assert why is not None, launcher.out[-2:]
    assert 0 <= int(why[1]) <= int(why[2])
    assert launcher.out[-1] == (f"hercs up: run e2e finished; run directory: {run_dir}; "
                                f"its episodes: hercs view {run_dir}")
    assert load_yaml(RunDir(run_dir).config).run.name == "e2e"
    rows = list(csv.DictReader(RunDir(run_dir).metrics.open()))
    assert [int(r["epoch"]) for r in rows] == [1, 2]
    assert [r["cluster_model_version"] for r in rows] == ["0", "0"]
    # The updates' wait for batches is accounted per epoch, within the epoch's wall time.
    walls = [float(rows[0]["wall_s"]), float(rows[1]["wall_s"]) - float(rows[0]["wall_s"])]
    assert all(0.0 <= float(r["batch_wait_s"]) <= w for r, w in zip(rows, walls, strict=True))
    assert not [i for i, pid in launcher.child_pids.items() if process_alive(pid)]


@pytest.mark.slow
def test_up_on_the_authors_v1_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A short real run on FetchReach-v1 (mujoco-py and MuJoCo 2.1, `make mujoco-py`), its
    processes started with neither LD_LIBRARY_PATH nor MUJOCO_PY_MUJOCO_PATH set: an epoch is
    trained and evaluated on v1, and config.yaml records the version."""
    skip_without_mujoco_py()
    for name in ("LD_LIBRARY_PATH", "MUJOCO_PY_MUJOCO_PATH", "MUJOCO_PY_FORCE_CPU"):
        monkeypatch.delenv(name, raising=False)  # hercs.rl.envs set them in this process
    _, run_dir = up_to_the_end(tmp_path, "v1", [
        "--method", "her-cs", "--epochs", "1", "--set", "task.env_version=v1",
        "--set", "training.cycles_per_epoch=2", "--set", "training.eval_episodes=2"], timeout_s=90)
    assert load_yaml(RunDir(run_dir).config).task.spec.env_id == "FetchReach-v1"
    rows = list(csv.DictReader(RunDir(run_dir).metrics.open()))
    assert [int(r["epoch"]) for r in rows] == [1] and int(rows[0]["episodes"]) >= 8
    evaluator = RunDir(run_dir).log("evaluator-0").read_text()
    assert "task reach (FetchReach-v1)" in evaluator and "epoch 1 (weights version" in evaluator
    assert len(list(read_episode_messages(run_dir))) >= 8, "the actor's v1 episodes were logged"


@pytest.mark.full
@pytest.mark.slow
@pytest.mark.skipif(not all(find_spec(m) for m in SERVICE_MODULES),
                    reason="a service module is not written yet")
def test_lockstep_run_acts_every_cycle_with_that_cycles_weights(tmp_path: Path) -> None:
    """`training.schedule=lockstep` with the real services, two actors and HER-CS refitting
    every 8 failures: the episode log holds cycle after cycle of 4 episodes, episode i acted
    with weights version i // 4 (the reference's schedule), and metrics.csv's policy lag
    against that schedule is 0."""
    launcher, run_dir = up_to_the_end(tmp_path, "lockstep", [
        "--method", "her-cs", "--epochs", "2", "--actors", "2",
        "--set", "training.schedule=lockstep", "--set", "training.cycles_per_epoch=3",
        "--set", "training.eval_episodes=2", "--set", "cluster.k=2",
        "--set", "cluster.fgb_size=8"], timeout_s=120)
    logged = list(read_episode_messages(run_dir))
    assert [episode_id for episode_id, _ in logged] == list(range(len(logged)))
    assert len(logged) >= 2 * 3 * 4, "every one of the 6 cycles had its 4 episodes"
    versions = [int(msg.policy_version) for _, msg in logged]
    assert versions == [i // 4 for i in range(len(logged))], versions
    rows = list(csv.DictReader(RunDir(run_dir).metrics.open()))
    assert [float(r["policy_lag"]) for r in rows] == [0.0, 0.0]
    assert [int(r["weights_version"]) for r in rows] == [3, 6]
    assert any(msg.failures_seen for msg in read_cluster_models(run_dir)), \
        "the clusterer refitted during the run (the lockstep gate waited for its models)"
    # the epoch lines show the replay's model and its episodes in each of the k = 2 clusters
    last_epoch = [line for line in launcher.out if line.startswith("epoch 2/2  success")][-1]
    shown = re.search(r"  clusters v(\d+) \[(\d+) (\d+)\]", last_epoch)
    assert shown is not None, last_epoch
    version, *sizes = (int(n) for n in shown.groups())
    assert version >= int(rows[-1]["cluster_model_version"]) >= 1
    assert 0 < sum(sizes) <= len(logged), "the stored episodes, each in one cluster"
    assert launcher.out[-1].endswith(f"; its episodes and clusters: hercs view {run_dir}")


# metrics.csv columns that depend on the computation alone. Left out: wall time and rates, and
# replay_size and cluster_sizes, which are read from the replay when the row is written, by
# then holding a varying part of the next cycle's episodes (the actor starts it as soon as the
# cycle's weights are out).
COMPUTED_COLUMNS = ("env_steps", "episodes", "updates", "success_rate", "mean_final_distance",
                    "weights_version", "cluster_model_version", "critic_loss", "actor_loss",
                    "q_mean")


@pytest.mark.full
@pytest.mark.slow
@pytest.mark.skipif(not all(find_spec(m) for m in SERVICE_MODULES),
                    reason="a service module is not written yet")
def test_lockstep_runs_with_one_seed_compute_the_same_numbers(tmp_path: Path) -> None:
    """Lockstep with one actor is reproducible from the root seed on one machine, whatever the
    timing (docs/DESIGN.md §10): two identical FetchReach HER-CS runs started side by side,
    so that they compete for the cores, log the same episodes (observations, goals, actions,
    weights version) and write the same losses, Q, evaluations and cluster model versions."""
    names = ("twin-a", "twin-b")
    launchers = [Launcher(
        [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--method", "her-cs",
         "--epochs", "2", "--actors", "1", "--seed", "7", "--run", name, "--run-dir",
         str(tmp_path / "runs"), "--listen", free_endpoint(),
         "--set", "training.schedule=lockstep", "--set", "training.cycles_per_epoch=3",
         "--set", "training.eval_episodes=4", "--set", "cluster.k=2",
         "--set", "cluster.fgb_size=8"],
        cwd=tmp_path) for name in names]
    try:
        for launcher in launchers:
            assert launcher.finish(timeout_s=180) == 0, "\n".join(launcher.out + launcher.err)
    finally:
        for launcher in launchers:
            launcher.kill()
    runs = [tmp_path / "runs" / name for name in names]

    def episodes(run_dir: Path) -> list[tuple[int, bytes, bytes, bytes, bytes, int]]:
        return [(i, m.obs.data, m.ag.data, m.g.data, m.actions.data, int(m.policy_version))
                for i, m in read_episode_messages(run_dir)]

    first, second = (episodes(r) for r in runs)
    # the 24 episodes of the 6 trained cycles, and those of the next cycle that each run
    # logged before it stopped (how many is timing: the actor starts it with the last weights)
    both = min(len(first), len(second))
    assert both >= 2 * 3 * 4 and first[:both] == second[:both], \
        "the two runs logged different episodes"
    computed = [[{c: row[c] for c in COMPUTED_COLUMNS}
                 for row in csv.DictReader(RunDir(r).metrics.open())] for r in runs]
    assert len(computed[0]) == 2 and computed[0] == computed[1]
    assert float(computed[0][-1]["critic_loss"]) > 0.0, "the learner updated"
