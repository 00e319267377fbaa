"""`hercs sweep` (hercs/apps/sweep/: grid.py, runner.py, cells.py, report.py): the grid plan, its
names, resume rules, publishing, and its quick mode end to end. Variants, the manifest, the
report's statistics: test_sweep_variants.py."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hercs.apps import provenance
from hercs.apps.sweep import cells as sc
from hercs.apps.sweep import grid as se
from hercs.apps.sweep import report as sr
from hercs.apps.sweep import runner as sweep_runner
from hercs.run.rundir import RunDir
from tests.support import REPO
from tests.unit.apps.sweep_runs import finished_run


def test_grid_is_seed_major_so_every_method_gets_its_seeds_together() -> None:
    cells = sc.plan_grid(["push", "slide"], ["her", "her-cs"], [1, 2])
    assert [c.name for c in cells] == [
        "push-her-s1", "push-her-cs-s1", "slide-her-s1", "slide-her-cs-s1",
        "push-her-s2", "push-her-cs-s2", "slide-her-s2", "slide-her-cs-s2"]


def test_variant_runs_are_named_after_their_schedule_and_precision() -> None:
    names = [c.name for c in sc.plan_grid(["push"], ["her-cs"], [2], "lockstep", "bf16")]
    assert names == ["push-her-cs-lockstep-bf16-s2"]
    assert sc.GridRun("push", "her-cs", 1, precision="bf16").name == "push-her-cs-bf16-s1"
    cmd = sc.up_command(sc.GridRun("push", "her-ebp-cs", 1, precision="bf16"), epochs=1,
                        run_root=Path("/tmp"), port=1, actors=1, overrides=[])
    sets = [cmd[i + 1] for i, arg in enumerate(cmd) if arg == "--set"]
    assert sets == ["training.schedule=async", "learner.precision=bf16", "task.env_version=v4"]


def test_v1_runs_are_named_after_their_env_version_and_v4_names_stay() -> None:
    cells = sc.plan_grid(["push"], ["her-cs"], [2], "lockstep", env_version="v1")
    assert [c.name for c in cells] == ["push-v1-her-cs-lockstep-s2"]
    assert (cells[0].env_id, sc.GridRun("pick", "her", 1).env_id) == (
        "FetchPush-v1", "FetchPickAndPlace-v4")
    assert sc.GridRun("push", "her", 1, env_version="v4").name == "push-her-s1"
    cmd = sc.up_command(cells[0], epochs=1, run_root=Path("/tmp"), port=1, actors=1,
                        overrides=[])
    assert cmd[cmd.index("--run") + 1] == "push-v1-her-cs-lockstep-s2"
    assert "task.env_version=v1" in cmd
    assert sr.done_key({"method": "her-cs", "env_version": "v1"}) == "her-cs/v1"
    assert sr.done_key({"method": "her-cs"}) == "her-cs"  # a record from before v1

def test_v1_and_v4_grids_report_apart(tmp_path: Path) -> None:
    v4, v1 = sc.GridRun("push", "her-cs", 1), sc.GridRun("push", "her-cs", 1, env_version="v1")
    finished_run(tmp_path / "runs", v4, [0.2, 0.4, 0.6])
    finished_run(tmp_path / "runs", v1, [0.9, 0.9, 0.9])
    written = sr.write_reports([v4, v1], tmp_path / "runs", tmp_path / "out", command="x")
    assert sorted(p.name for p in written) == ["push-v1.md", "push-v1.png", "push.md",
                                               "push.png"]
    v4_md, v1_md = (tmp_path / "out" / "push.md").read_text(), (
        tmp_path / "out" / "push-v1.md").read_text()
    assert v4_md.startswith("# FetchPush: hercs sweep report\n")
    assert v1_md.startswith("# FetchPush-v1: hercs sweep report\n")
    assert "| HER-CS (ours) | 1 | 3 |" in v4_md and "(v1)" not in v4_md
    assert "| HER-CS, authors' simulator (v1) (ours) | 1 | 3 |" in v1_md
    assert "- runs: her-cs/v1 s1 " in v1_md


def test_up_command_names_the_run_after_its_cell_and_passes_overrides(tmp_path: Path) -> None:
    cell = sc.GridRun("push", "her-cs", 3)
    cmd = sc.up_command(cell, epochs=7, run_root=tmp_path, port=40123, actors=2,
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
    assert not sc.is_done(run)
    moved = sc.set_aside(run, tmp_path)
    assert not run.exists()
    assert moved.parent == tmp_path / sc.UNFINISHED_DIR
    assert RunDir(moved).log("learner-0").read_text() == "killed at epoch 12"


def test_bad_grid_arguments_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert se.main(["--seeds", "0", "--report-only"]) == 2
    assert "--seeds must be at least 1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        se.main(["--methods", "her-xx"])


def test_dry_run_says_what_each_cell_would_do_and_starts_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_training(*args: object, **kwargs: object) -> None:
        raise AssertionError("a dry run started the grid")

    monkeypatch.setattr(se, "run_grid", no_training)
    root, committed = tmp_path / "runs", tmp_path / "committed"
    finished_run(root, sc.GridRun("push", "her", 1), [0.5] * 7)
    RunDir(root / "push-her-cs-s1").config.parent.mkdir(parents=True)
    RunDir(root / "push-her-cs-s1").config.write_text("run: {name: push-her-cs-s1}\n")
    (root / "push-her-s2").mkdir()  # a folder that never saved its config
    finished_run(committed, sc.GridRun("push", "her", 3), [0.5] * 7)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))

    assert se.main(["--tasks", "push", "--methods", "her", "her-cs", "--seeds", "3",
                    "--epochs", "7", "--run-dir", str(root), "--committed", str(committed),
                    "--dry-run"]) == 0
    out = capsys.readouterr().out.splitlines()
    plan = {line.split(":")[0]: line for line in out if line.startswith("[")}
    assert list(plan) == ["[skip] push-her-s1", "[resume] push-her-cs-s1",
                          "[redo] push-her-s2", "[start] push-her-cs-s2",
                          "[skip] push-her-s3", "[start] push-her-cs-s3"]
    assert str(committed / "push-her-s3") in plan["[skip] push-her-s3"]
    assert f"hercs up --resume {root / 'push-her-cs-s1'} --epochs 7" in plan[
        "[resume] push-her-cs-s1"]
    assert ("hercs up --task push --method her-cs --seed 3 --epochs 7 --run push-her-cs-s3"
            in plan["[start] push-her-cs-s3"])
    assert out[-1] == "nothing was started (--dry-run)"
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


@pytest.mark.full
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
    tallies = [line for line in first.stdout.splitlines() if line.startswith("[sweep] ")]
    assert tallies[-1] == "[sweep] 2 of 2 done, 0 running, 0 left", first.stdout
    for name in ("reach-her-s1", "reach-her-cs-s1"):
        done = json.loads((tmp_path / "runs" / name / sc.DONE_FILE).read_text())
        assert (done["task"], done["epochs"], done["env_id"]) == ("reach", 1, "FetchReach-v4")
        assert done["machine"] == provenance.machine_identity()  # one seed differs across CPUs
        assert done["started_commit"] == done["commit"]  # one life: started and finished
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
    assert "| HER | 1 | 1 | – |" in report  # no authors' rows for Reach to tell ours apart
    assert "| HER-CS | 1 | 1 | – |" in report
    assert (tmp_path / "results" / "reach.png").stat().st_size > 10_000

    # Resume: a finished run is skipped; one stopped before it was marked done is continued
    # with `hercs up --resume` (its epoch kept, not retrained); a folder that never got a
    # config is moved aside and started again.
    # A run whose folder is gone but whose small files are committed (another machine) is
    # done: skipped, and reported from the committed copy.
    (tmp_path / "runs" / "reach-her-cs-s1" / sc.DONE_FILE).unlink()  # as if interrupted,
    shutil.rmtree(tmp_path / "committed" / "reach-her-cs-s1")  # so never committed either
    shutil.rmtree(tmp_path / "runs" / "reach-her-s1")
    # as if its first life had run from another commit: the resumed run keeps that one
    logs = tmp_path / "runs" / sweep_runner.LOG_DIR
    (logs / f"reach-her-cs-s1{sweep_runner.STARTED_SUFFIX}").write_text("0ld5ta7\n")
    second = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=REPO)
    assert second.returncode == 0, second.stdout + second.stderr
    assert "[skip] reach-her-s1: finished and committed" in second.stdout
    assert "| HER | 1 | 1 | – |" in (tmp_path / "results" / "reach.md").read_text()
    assert "[resume] reach-her-cs-s1" in second.stdout
    assert [line for line in second.stdout.splitlines() if line.startswith("[sweep] ")] == [
        "[sweep] 1 of 2 done, 1 running, 0 left; eta once the first run ends",
        "[sweep] 2 of 2 done, 0 running, 0 left"], second.stdout
    assert "[start] reach-her-s1" not in second.stdout
    done = json.loads((tmp_path / "runs" / "reach-her-cs-s1" / sc.DONE_FILE).read_text())
    assert done["resumed"] is True and "--resume" in done["command"]
    assert done["started_commit"] == "0ld5ta7" and done["commit"] != "0ld5ta7"
    rows = RunDir(tmp_path / "runs" / "reach-her-cs-s1").metrics.read_text().splitlines()
    assert len(rows) == 2, "the resumed run kept its one epoch and trained no other"

    manifest = json.loads((tmp_path / "runs" / sc.MANIFEST).read_text())
    assert [(c["name"], c["state"]) for c in manifest["cells"]] == [
        ("reach-her-s1", "done"), ("reach-her-cs-s1", "done")]
    assert manifest["cells"][1]["machine"] == provenance.machine_identity()
    # the report again from the manifest alone, as `hercs sweep report` writes it
    again = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "sweep", "report",
                            str(tmp_path / "runs"), "--out", str(tmp_path / "again"),
                            "--committed", str(tmp_path / "committed"), "--reps", "200"],
                           capture_output=True, text=True, timeout=300, cwd=REPO)
    assert again.returncode == 0, again.stdout + again.stderr
    text = (tmp_path / "again" / "reach.md").read_text()
    assert "| HER | 1 | " in text and "| HER-CS | 1 | " in text  # the arms over seeds


def test_a_v4_grid_with_a_stiffer_gripper_weld_is_named_and_launched_apart() -> None:
    cell = sc.GridRun("push", "her-cs", 2, weld_torquescale=4.0)
    assert cell.name == "push-ts4-her-cs-s2"
    assert sc.GridRun("push", "her-ebp-cs", 2, weld_torquescale=4.0).name == (
        "push-ts4-eps1e-3-her-ebp-cs-s2")  # v4's ε, 1e-3, is marked
    cmd = sc.up_command(cell, epochs=3, run_root=Path("/r"), port=1, actors=1, overrides=[])
    assert cmd[-2:] == ["--set", "task.weld_torquescale=4"]
    plain = sc.up_command(sc.GridRun("push", "her", 1), epochs=3, run_root=Path("/r"), port=1,
                          actors=1, overrides=[])
    assert not any("weld_torquescale" in a for a in plain)


def test_a_grid_with_another_energy_floor_is_named_and_launched_apart() -> None:
    cell = sc.GridRun("push", "her-ebp-cs", 3, energy_epsilon=1e-3)
    assert cell.name == "push-eps1e-3-her-ebp-cs-s3"
    assert sc.GridRun("push", "her-ebp", 1, energy_epsilon=2.5e-4).name == (
        "push-eps2.5e-4-her-ebp-s1")
    cmd = sc.up_command(cell, epochs=3, run_root=Path("/r"), port=1, actors=1, overrides=[])
    assert cmd[-2:] == ["--set", "energy.epsilon=0.001"]
    plain = sc.up_command(sc.GridRun("push", "her-ebp-cs", 3), epochs=3, run_root=Path("/r"),
                          port=1, actors=1, overrides=[])
    assert not any("energy.epsilon" in a for a in plain)  # the config's default decides
    assert se.main(["--energy-epsilon", "0", "--report-only", "--tasks", "push"]) == 2


def test_an_ebp_cell_is_named_after_the_epsilon_its_environment_gives_it() -> None:
    """Since v4's default ε became 1e-3 (docs/DESIGN.md §9.3) a plain v4 EBP cell is the
    committed `push-eps1e-3-…` runs' experiment and is named like them, so that a sweep with
    --committed counts them as done; the runs of 1e-6 keep their plain names; v1's default
    stays 1e-6; HER and HER-CS, which ε does not touch, are never marked."""
    assert sc.GridRun("push", "her-ebp", 1).name == "push-eps1e-3-her-ebp-s1"
    assert sc.GridRun("push", "her-ebp", 1).epsilon == 1e-3
    assert sc.GridRun("push", "her-ebp", 1, energy_epsilon=1e-6).name == "push-her-ebp-s1"
    assert sc.GridRun("push", "her-ebp-cs", 1, env_version="v1").name == "push-v1-her-ebp-cs-s1"
    assert sc.GridRun("push", "her-ebp-cs", 1, env_version="v1").epsilon == 1e-6
    assert sc.GridRun("push", "her-cs", 1, energy_epsilon=1e-3).name == "push-her-cs-s1"
    assert sc.GridRun("push", "her", 1, env_version="v1").name == "push-v1-her-s1"
    # a variant that sets ε, or unsets it, or changes the env version, is named after the ε
    # it runs with
    floor = sc.GridRun("push", "her-ebp", 1, variant="floor",
                       variant_overrides=("energy.epsilon=1e-6",))
    assert (floor.epsilon, floor.name) == (1e-6, "push-her-ebp-floor-s1")
    unset = sc.GridRun("push", "her-ebp", 1, energy_epsilon=1e-6, variant="unset",
                       variant_overrides=("energy.epsilon=null",))
    assert unset.epsilon == 1e-3
    old_sim = sc.GridRun("push", "her-ebp", 1, variant="old",
                         variant_overrides=("task.env_version=v1",))
    assert old_sim.epsilon == 1e-6


def test_a_sweep_refuses_a_set_of_what_its_runs_are_named_after(capsys) -> None:
    """`--set energy.epsilon=1e-6` would train at 1e-6 a run named (and, with --committed,
    counted done) as v4's 1e-3 one: the sweep's own flags set what a name says."""
    for item, flag in (("energy.epsilon=1e-6", "--energy-epsilon"),
                       ("task.env_version=v1", "--env-version"),
                       ("learner.precision=bf16", "--precision")):
        assert se.main(["--set", item, "--report-only", "--tasks", "push"]) == 2
        assert f"give it with {flag}" in capsys.readouterr().err


def test_a_sweep_begun_with_another_epsilon_is_not_passed_over(tmp_path: Path) -> None:
    """A v4 EBP sweep begun before the default ε became 1e-3 has cells named without `eps`
    in its manifest: run again without --energy-epsilon it would plan `eps1e-3` cells and
    pass its runs over; it is refused with the flag that goes on with them."""
    old = sc.plan_grid(["push"], ["her", "her-ebp"], [1, 2], energy_epsilon=1e-6)
    sc.write_manifest(tmp_path, old, {}, command="hercs sweep", epochs=50, committed=None)
    new = sc.plan_grid(["push"], ["her", "her-ebp"], [1, 2])
    problem = sc.epsilon_changed(new, tmp_path)
    assert problem is not None and "push-her-ebp-s1, push-her-ebp-s2" in problem
    assert "--energy-epsilon 1e-06" in problem
    assert sc.epsilon_changed(old, tmp_path) is None  # the same ε goes on
    assert sc.epsilon_changed(new, tmp_path / "elsewhere") is None  # no sweep there


def test_the_first_finished_run_of_a_cell_publishes_its_best_policy(tmp_path: Path) -> None:
    runs, committed = tmp_path / "runs", tmp_path / "committed"
    committed.mkdir()
    for name in ("push-her-cs-s1", "push-her-cs-s2", "push-her-s1"):
        RunDir(runs / name).checkpoints.mkdir(parents=True)
        RunDir(runs / name).metrics.write_text("epoch\n1\n")
        RunDir(runs / name).checkpoint("best").write_bytes(name.encode())
    for name in ("push-her-cs-s1", "push-her-cs-s2", "push-her-s1"):
        sc.copy_small_files(runs / name, committed)
    published = sorted(p.parent.parent.name for p in committed.glob("*/checkpoints/best.pt"))
    assert published == ["push-her-cs-s1", "push-her-s1"]  # one per cell, the first
    assert RunDir(committed / "push-her-cs-s2").metrics.is_file()
    # copying the publishing run again keeps its own policy
    sc.copy_small_files(runs / "push-her-cs-s1", committed)
    assert RunDir(committed / "push-her-cs-s1").checkpoint("best").read_bytes() == \
        b"push-her-cs-s1"
