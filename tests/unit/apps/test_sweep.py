"""`hercs sweep` (hercs/apps/sweep.py, sweep_cells.py, sweep_report.py): the grid plan, its
variants, resume rules, the manifest, the report's statistics, and its quick mode end to end."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hercs.apps import sweep as se
from hercs.apps import sweep_cells as sc
from hercs.apps import sweep_report as sr
from hercs.apps import sweep_stats
from hercs.errors import ConfigError
from hercs.run.rundir import RunDir

REPO = Path(__file__).resolve().parents[3]


def test_grid_is_seed_major_so_every_method_gets_its_seeds_together() -> None:
    cells = se.plan_grid(["push", "slide"], ["her", "her-cs"], [1, 2])
    assert [c.name for c in cells] == [
        "push-her-s1", "push-her-cs-s1", "slide-her-s1", "slide-her-cs-s1",
        "push-her-s2", "push-her-cs-s2", "slide-her-s2", "slide-her-cs-s2"]


def test_variant_runs_are_named_after_their_schedule_and_precision() -> None:
    names = [c.name for c in se.plan_grid(["push"], ["her-cs"], [2], "lockstep", "bf16")]
    assert names == ["push-her-cs-lockstep-bf16-s2"]
    assert se.GridRun("push", "her-ebp-cs", 1, precision="bf16").name == "push-her-ebp-cs-bf16-s1"
    cmd = se.up_command(se.GridRun("push", "her-ebp-cs", 1, precision="bf16"), epochs=1,
                        run_root=Path("/tmp"), port=1, actors=1, overrides=[])
    sets = [cmd[i + 1] for i, arg in enumerate(cmd) if arg == "--set"]
    assert sets == ["training.schedule=async", "learner.precision=bf16", "task.env_version=v4"]


def test_v1_runs_are_named_after_their_env_version_and_v4_names_stay() -> None:
    cells = se.plan_grid(["push"], ["her-cs"], [2], "lockstep", env_version="v1")
    assert [c.name for c in cells] == ["push-v1-her-cs-lockstep-s2"]
    assert (cells[0].env_id, se.GridRun("pick", "her", 1).env_id) == (
        "FetchPush-v1", "FetchPickAndPlace-v4")
    assert se.GridRun("push", "her", 1, env_version="v4").name == "push-her-s1"
    cmd = se.up_command(cells[0], epochs=1, run_root=Path("/tmp"), port=1, actors=1,
                        overrides=[])
    assert cmd[cmd.index("--run") + 1] == "push-v1-her-cs-lockstep-s2"
    assert "task.env_version=v1" in cmd
    assert sr.done_key({"method": "her-cs", "env_version": "v1"}) == "her-cs/v1"
    assert sr.done_key({"method": "her-cs"}) == "her-cs"  # a record from before v1


def _finished(root: Path, cell, success: list[float]) -> None:
    """A run folder as run_grid leaves it: config.yaml, metrics.csv, bench_done.json."""
    run = root / cell.name
    run.mkdir(parents=True)
    RunDir(run).config.write_text(
        f"run: {{method: {cell.method}, seed: {cell.seed}}}\n"
        f"task: {{name: {cell.task}, env_version: {cell.env_version}}}\n")
    rows = [f"{e},{v}" for e, v in enumerate(success, start=1)]
    RunDir(run).metrics.write_text("\n".join(["epoch,success_rate", *rows]) + "\n")
    (run / se.DONE_FILE).write_text(json.dumps(
        {"task": cell.task, "method": cell.method, "seed": cell.seed,
         "env_version": cell.env_version, "env_id": cell.env_id, "epochs": len(success),
         "wall_s": 60.0, "commit": "abc"}))


def test_v1_and_v4_grids_report_apart(tmp_path: Path) -> None:
    v4, v1 = se.GridRun("push", "her-cs", 1), se.GridRun("push", "her-cs", 1, env_version="v1")
    _finished(tmp_path / "runs", v4, [0.2, 0.4, 0.6])
    _finished(tmp_path / "runs", v1, [0.9, 0.9, 0.9])
    written = se.write_reports([v4, v1], tmp_path / "runs", tmp_path / "out", command="x")
    assert sorted(p.name for p in written) == ["push-v1.md", "push-v1.png", "push.md",
                                               "push.png"]
    v4_md, v1_md = (tmp_path / "out" / "push.md").read_text(), (
        tmp_path / "out" / "push-v1.md").read_text()
    assert v4_md.startswith("# FetchPush: hercs sweep report\n")
    assert v1_md.startswith("# FetchPush-v1: hercs sweep report\n")
    assert "| HER-CS (ours) | 1 | 3 |" in v4_md and "(v1)" not in v4_md
    assert "| HER-CS (v1) (ours) | 1 | 3 |" in v1_md and "- runs: her-cs/v1 s1 " in v1_md


def test_up_command_names_the_run_after_its_cell_and_passes_overrides(tmp_path: Path) -> None:
    cell = se.GridRun("push", "her-cs", 3)
    cmd = se.up_command(cell, epochs=7, run_root=tmp_path, port=40123, actors=2,
                        overrides=["ddpg.polyak=0.9"])
    args = cmd[cmd.index("up") + 1:]
    pairs = dict(zip(args[::2], args[1::2], strict=True))
    assert pairs == {"--task": "push", "--method": "her-cs", "--seed": "3", "--epochs": "7",
                     "--run": "push-her-cs-s3", "--run-dir": str(tmp_path), "--actors": "2",
                     "--listen": "tcp/127.0.0.1:40123", "--set": "ddpg.polyak=0.9"}


def test_unfinished_run_is_set_aside_and_kept(tmp_path: Path) -> None:
    run = tmp_path / "push-her-s1"
    RunDir(run).logs.mkdir(parents=True)
    RunDir(run).log("learner-0").write_text("killed at epoch 12")
    assert not se.is_done(run)
    moved = se.set_aside(run, tmp_path)
    assert not run.exists()
    assert moved.parent == tmp_path / sc.UNFINISHED_DIR
    assert RunDir(moved).log("learner-0").read_text() == "killed at epoch 12"


def test_bad_grid_arguments_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert se.main(["--seeds", "0", "--report-only"]) == 2
    assert "--seeds must be at least 1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        se.main(["--methods", "her-xx"])


@pytest.mark.integration
@pytest.mark.slow
def test_quick_grid_trains_resumes_and_reports(tmp_path: Path) -> None:
    """Two real 1-epoch runs through `hercs up`; a second call skips the finished one and
    resumes the unfinished one; the report holds the table with our rows beside the
    authors'."""
    cmd = [sys.executable, "-m", "hercs.apps.cli", "sweep", "--quick",
           "--methods", "her", "her-cs", "--seeds", "1", "--run-dir", str(tmp_path / "runs"),
           "--out", str(tmp_path / "results"), "--committed", str(tmp_path / "committed")]
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=REPO)
    assert first.returncode == 0, first.stdout + first.stderr
    for name in ("reach-her-s1", "reach-her-cs-s1"):
        done = json.loads((tmp_path / "runs" / name / se.DONE_FILE).read_text())
        assert (done["task"], done["epochs"], done["env_id"]) == ("reach", 1, "FetchReach-v4")
        assert done["machine"] == se.machine_identity()  # one seed differs across CPUs
        rows = RunDir(tmp_path / "runs" / name).metrics.read_text().strip().splitlines()
        assert len(rows) == 2  # header + the one epoch
        committed = tmp_path / "committed" / name  # the small files, ready to commit
        # the small files, and the first (here: only) run of its cell publishes its policy
        assert sorted(p.name for p in committed.iterdir()) == [
            "bench_done.json", "checkpoints", "config.yaml", "metrics.csv"]
        assert [p.name for p in RunDir(committed).checkpoints.iterdir()] == ["best.pt"]
        assert RunDir(committed).metrics.read_text() == (
            RunDir(tmp_path / "runs" / name).metrics).read_text()

    report = (tmp_path / "results" / "reach.md").read_text()
    assert "| HER (ours) | 1 | 1 |" in report
    assert "| HER-CS (ours) | 1 | 1 |" in report
    assert (tmp_path / "results" / "reach.png").stat().st_size > 10_000

    # Resume: a finished run is skipped; one stopped before it was marked done is continued
    # with `hercs up --resume` (its epoch kept, not retrained); a folder that never got a
    # config is moved aside and started again.
    # A run whose folder is gone but whose small files are committed (another machine) is
    # done: skipped, and reported from the committed copy.
    (tmp_path / "runs" / "reach-her-cs-s1" / se.DONE_FILE).unlink()  # as if interrupted,
    shutil.rmtree(tmp_path / "committed" / "reach-her-cs-s1")  # so never committed either
    shutil.rmtree(tmp_path / "runs" / "reach-her-s1")
    second = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=REPO)
    assert second.returncode == 0, second.stdout + second.stderr
    assert "[skip] reach-her-s1: finished and committed" in second.stdout
    assert "| HER (ours) | 1 | 1 |" in (tmp_path / "results" / "reach.md").read_text()
    assert "[resume] reach-her-cs-s1" in second.stdout
    assert "[start] reach-her-s1" not in second.stdout
    done = json.loads((tmp_path / "runs" / "reach-her-cs-s1" / se.DONE_FILE).read_text())
    assert done["resumed"] is True and "--resume" in done["command"]
    rows = RunDir(tmp_path / "runs" / "reach-her-cs-s1").metrics.read_text().splitlines()
    assert len(rows) == 2, "the resumed run kept its one epoch and trained no other"

    manifest = json.loads((tmp_path / "runs" / sc.MANIFEST).read_text())
    assert [(c["name"], c["state"]) for c in manifest["cells"]] == [
        ("reach-her-s1", "done"), ("reach-her-cs-s1", "done")]
    assert manifest["cells"][1]["machine"] == se.machine_identity()
    # the report again from the manifest alone, as `hercs sweep report` writes it
    again = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "sweep", "report",
                            str(tmp_path / "runs"), "--out", str(tmp_path / "again"),
                            "--committed", str(tmp_path / "committed"), "--reps", "200"],
                           capture_output=True, text=True, timeout=300, cwd=REPO)
    assert again.returncode == 0, again.stdout + again.stderr
    text = (tmp_path / "again" / "reach.md").read_text()
    assert "| HER | 1 | " in text and "| HER-CS | 1 | " in text  # the arms over seeds


def test_a_v4_grid_with_a_stiffer_gripper_weld_is_named_and_launched_apart() -> None:
    cell = se.GridRun("push", "her-ebp-cs", 2, weld_torquescale=4.0)
    assert cell.name == "push-ts4-her-ebp-cs-s2"
    cmd = se.up_command(cell, epochs=3, run_root=Path("/r"), port=1, actors=1, overrides=[])
    assert cmd[-2:] == ["--set", "task.weld_torquescale=4"]
    plain = se.up_command(se.GridRun("push", "her", 1), epochs=3, run_root=Path("/r"), port=1,
                          actors=1, overrides=[])
    assert not any("weld_torquescale" in a for a in plain)


def test_a_grid_with_another_energy_floor_is_named_and_launched_apart() -> None:
    cell = se.GridRun("push", "her-ebp-cs", 3, energy_epsilon=1e-3)
    assert cell.name == "push-eps1e-3-her-ebp-cs-s3"
    assert se.GridRun("push", "her-ebp", 1, energy_epsilon=2.5e-4).name == (
        "push-eps2.5e-4-her-ebp-s1")
    cmd = se.up_command(cell, epochs=3, run_root=Path("/r"), port=1, actors=1, overrides=[])
    assert cmd[-2:] == ["--set", "energy.epsilon=0.001"]
    plain = se.up_command(se.GridRun("push", "her-ebp-cs", 3), epochs=3, run_root=Path("/r"),
                          port=1, actors=1, overrides=[])
    assert not any("energy.epsilon" in a for a in plain)
    assert se.main(["--energy-epsilon", "0", "--report-only", "--tasks", "push"]) == 2


def test_the_first_finished_run_of_a_cell_publishes_its_best_policy(tmp_path: Path) -> None:
    runs, committed = tmp_path / "runs", tmp_path / "committed"
    committed.mkdir()
    for name in ("push-her-cs-s1", "push-her-cs-s2", "push-her-s1"):
        RunDir(runs / name).checkpoints.mkdir(parents=True)
        RunDir(runs / name).metrics.write_text("epoch\n1\n")
        RunDir(runs / name).checkpoint("best").write_bytes(name.encode())
    for name in ("push-her-cs-s1", "push-her-cs-s2", "push-her-s1"):
        se.copy_small_files(runs / name, committed)
    published = sorted(p.parent.parent.name for p in committed.glob("*/checkpoints/best.pt"))
    assert published == ["push-her-cs-s1", "push-her-s1"]  # one per cell, the first
    assert RunDir(committed / "push-her-cs-s2").metrics.is_file()
    # copying the publishing run again keeps its own policy
    se.copy_small_files(runs / "push-her-cs-s1", committed)
    assert RunDir(committed / "push-her-cs-s1").checkpoint("best").read_bytes() == \
        b"push-her-cs-s1"


# ------------------------------------------------------------------ variants and manifest

def test_a_variant_is_an_arm_of_its_own_named_and_launched_with_its_overrides() -> None:
    name, items = se.parse_variant("lr5e-4:ddpg.lr_actor=5e-4, ddpg.lr_critic=5e-4")
    assert (name, items) == ("lr5e-4", ("ddpg.lr_actor=5e-4", "ddpg.lr_critic=5e-4"))
    cells = se.plan_grid(["push"], ["her", "her-cs"], [1, 2], variants=[("", ()), (name, items)])
    assert [c.name for c in cells] == [
        "push-her-s1", "push-her-cs-s1", "push-her-lr5e-4-s1", "push-her-cs-lr5e-4-s1",
        "push-her-s2", "push-her-cs-s2", "push-her-lr5e-4-s2", "push-her-cs-lr5e-4-s2"]
    assert cells[2].arm == "push-her-lr5e-4" and sr.arm_key(cells[2]) == "her/lr5e-4"
    cmd = se.up_command(cells[2], epochs=1, run_root=Path("/r"), port=1, actors=1,
                        overrides=["ddpg.polyak=0.9"])
    sets = [cmd[i + 1] for i, arg in enumerate(cmd) if arg == "--set"]
    assert sets[-3:] == ["ddpg.lr_actor=5e-4", "ddpg.lr_critic=5e-4", "ddpg.polyak=0.9"]
    plain = se.up_command(cells[0], epochs=1, run_root=Path("/r"), port=1, actors=1,
                          overrides=[])
    assert not any("lr_actor" in a for a in plain)


@pytest.mark.parametrize("text, why", [
    ("lr", "give NAME:FIELD=VALUE"), ("lr:", "give NAME:FIELD=VALUE"),
    ("lr:ddpg.lr_actor", "give NAME:FIELD=VALUE"), ("Big:ddpg.lr_actor=1", "lower-case"),
    ("s2:ddpg.lr_actor=1", "or a seed"),
])
def test_a_malformed_variant_is_refused_with_what_to_write(text: str, why: str) -> None:
    with pytest.raises(ConfigError, match=why):
        se.parse_variant(text)


def test_bad_variants_stop_the_sweep_before_any_run(capsys: pytest.CaptureFixture[str],
                                                    tmp_path: Path) -> None:
    base = ["--report-only", "--tasks", "push", "--run-dir", str(tmp_path / "r")]
    assert se.main([*base, "--variant", "lr:ddpg.lr_actor=fast"]) == 2
    assert "ddpg.lr_actor: got 'fast', must be a number" in capsys.readouterr().err
    assert se.main([*base, "--variant", "a:ddpg.polyak=0.9", "--variant", "a:ddpg.polyak=0.8"]
                   ) == 2
    assert "two --variant arms have one name" in capsys.readouterr().err
    assert se.main([*base, "--no-plain"]) == 2
    assert not (tmp_path / "r").exists()


def test_the_manifest_says_where_every_cell_stands_and_the_report_reads_it(
        tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    cells = se.plan_grid(["push"], ["her", "her-cs"], [1, 2])
    for cell, success in zip(cells[:3], ([0.1] * 12, [0.9] * 12, [0.3] * 12), strict=True):
        _finished(runs, cell, success)
    path = se.write_manifest(runs, cells, {cells[3]: "running"}, command="hercs sweep x",
                             epochs=12, committed=None)
    manifest = json.loads(path.read_text())
    assert [(c["name"], c["state"]) for c in manifest["cells"]] == [
        ("push-her-s1", "done"), ("push-her-cs-s1", "done"), ("push-her-s2", "done"),
        ("push-her-cs-s2", "running")]
    assert manifest["cells"][0]["commit"] == "abc" and manifest["command"] == "hercs sweep x"
    again, _ = sc.read_manifest(runs)
    assert again == cells
    assert se.main_report([str(runs), "--out", str(tmp_path / "out"), "--reps", "200",
                           "--compare", "HER-CS", "HER"]) == 0
    text = (tmp_path / "out" / "push.md").read_text()
    # HER-CS's one run (.90) beats both of HER's (.10, .30): P = 1 in every resample
    assert "| HER-CS | 1 | .90 [.90, .90] | .90 [.90, .90] | 1.00 [1.00, 1.00] |" in text
    assert "| HER | 2 | .20 [.10, .30] | .20 [.10, .30] | – |" in text
    assert "- P(HER-CS > HER) = 1.00 [1.00, 1.00]" in text
    assert "- not finished yet: push-her-cs-s2" in text
    with pytest.raises(ConfigError, match="no sweep here"):
        sc.read_manifest(tmp_path)


# ------------------------------------------------------------------------ its statistics

@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 8, 20])
def test_the_iqm_and_probability_of_improvement_equal_rliables(n: int) -> None:
    from rliable import metrics

    rng = np.random.default_rng(n)
    x, y = rng.random(n), np.round(rng.random(n + 2), 1)
    assert sweep_stats.iqm(x) == pytest.approx(metrics.aggregate_iqm(x[:, None]), abs=1e-12)
    assert sweep_stats.probability_of_improvement(x, y) == pytest.approx(
        metrics.probability_of_improvement(x[:, None], y[:, None]), abs=1e-12)


def test_bootstrap_intervals_by_hand() -> None:
    """Four runs 0, 0, 0, 1: resampled means are k/4, P(k >= 3) = 5.1 % and P(k = 4) = .4 %,
    so the 97.5th percentile is .75 and, with P(k = 0) = 32 %, the 2.5th is 0."""
    mean = sweep_stats.bootstrap([0, 0, 0, 1], np.mean, reps=4000)
    assert (mean.value, mean.low, mean.high) == (0.25, 0.0, 0.75)
    apart = sweep_stats.improvement([0.9, 0.8], [0.1, 0.2], reps=500)
    assert (apart.value, apart.low, apart.high) == (1.0, 1.0, 1.0)
    assert sweep_stats.Interval(0.5, 0.25, 1.0).format() == ".50 [.25, 1.00]"


@pytest.mark.parametrize("name", ["cs", "ebp-cs", "v1", "lockstep", "bf16", "ts4", "eps3"])
def test_a_variant_may_not_take_a_name_the_runs_naming_uses(name: str) -> None:
    # `her` + variant `cs` would be named like a her-cs run: push-her-cs-s1
    with pytest.raises(ConfigError, match="one hercs gives runs itself"):
        se.parse_variant(f"{name}:ddpg.polyak=0.9")


def test_repeated_tasks_and_methods_are_one_arm_each(capsys: pytest.CaptureFixture[str],
                                                     tmp_path: Path) -> None:
    assert se.main(["--report-only", "--tasks", "push", "push", "--methods", "her", "her",
                    "--seeds", "1", "--run-dir", str(tmp_path / "r")]) == 0
    assert "sweep: 1 runs (push × her × 1 arm × 1 seeds)" in capsys.readouterr().out


def test_manifest_writers_at_once_never_fail_or_leave_half_a_file(tmp_path: Path) -> None:
    """Slurm array tasks write the manifest together: each through a temporary file of its
    own and an atomic rename."""
    import threading

    cells = se.plan_grid(["push"], ["her", "her-cs"], [1, 2, 3])
    errors: list[BaseException] = []

    def write() -> None:
        try:
            for _ in range(30):
                se.write_manifest(tmp_path, cells, {}, command="x", epochs=1, committed=None)
                json.loads((tmp_path / sc.MANIFEST).read_text())  # always whole
        except BaseException as exc:  # collected for the assertion
            errors.append(exc)

    threads = [threading.Thread(target=write) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert [p.name for p in tmp_path.iterdir()] == [sc.MANIFEST]  # no temporary file left


def test_the_slurm_cells_keep_the_tasks_in_the_order_given() -> None:
    """The array's --cell-index values are the submitter's indices: the task's command must
    plan the same cells in the same order."""
    import argparse

    from hercs.apps.sweep_slurm import cell_command

    args = argparse.Namespace(methods=["her"], seeds=1, schedule="async", precision="fp32",
                              env_version="v4", weld_torquescale=1.0, energy_epsilon=1e-6,
                              actors=1, variants=[], no_plain=False)
    cmd = cell_command(args, ["reach", "push"], run_root=Path("/r"), committed=None, epochs=1,
                       overrides=[])
    assert cmd[cmd.index("--tasks") + 1:cmd.index("--tasks") + 3] == ["reach", "push"]


@pytest.mark.integration
@pytest.mark.slow
def test_a_killed_sweep_stops_its_runs_in_order_and_the_next_call_resumes_them(
        tmp_path: Path) -> None:
    """SIGTERM to the sweep (its runs are in sessions of their own, out of its reach
    otherwise): each run stops in order, the manifest says so, nothing is left running, and
    the same command continues the run from its checkpoint."""
    import signal
    import time

    cmd = [sys.executable, "-m", "hercs.apps.cli", "sweep", "--quick", "--methods", "her",
           "--seeds", "1", "--epochs", "100", "--run-dir", str(tmp_path / "runs")]
    sweep = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True)
    metrics = RunDir(tmp_path / "runs" / "reach-her-s1").metrics
    deadline = time.monotonic() + 300
    # the learner's first row: the run is training (a file has no event to await)
    while not (metrics.is_file() and len(metrics.read_text().splitlines()) >= 2):
        assert sweep.poll() is None and time.monotonic() < deadline, sweep.stdout.read()
        time.sleep(0.2)
    sweep.send_signal(signal.SIGTERM)
    out, _ = sweep.communicate(timeout=180)
    assert sweep.returncode == 130, out
    assert "hercs sweep: stopped; the same command resumes it" in out
    manifest = json.loads((tmp_path / "runs" / sc.MANIFEST).read_text())
    assert manifest["cells"][0]["state"] == "stopped (resumed by the next call)"
    log = (tmp_path / "runs" / "_logs" / "reach-her-s1.log").read_text()
    assert "hercs up: got SIGTERM, stopping the run" in log and "stopped; run directory" in log
    kept = len(metrics.read_text().splitlines()) - 1
    assert 1 <= kept < 100
    again = subprocess.run([*cmd[:-4], "--epochs", str(kept + 1), *cmd[-2:]], cwd=REPO,
                           capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "[resume] reach-her-s1" in again.stdout
    epochs = [int(line.split(",")[0]) for line in metrics.read_text().splitlines()[1:]]
    # the kept epochs, then more to the new end, none twice. The learner may have trained
    # past the last row before the stop (a row waits for its epoch's evaluation, and these
    # epochs take well under a second): the resumed learner then asks for those evaluations
    # again and writes their rows, even past the new --epochs; nothing is trained twice.
    assert epochs == list(range(1, len(epochs) + 1)) and epochs[-1] >= kept + 1
