"""`hercs up --resume` never discards results (issue 33, item 2): on real run directories (a
small learner's real checkpoint and metrics.csv), a folder whose files do not let the run
continue is refused with exit 2 before anything starts, saying why and what would work, and
nothing in it changes; a finished run says so and starts nothing; `--restart` starts over
with the old files set aside, never deleted."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from hercs.apps.cli.main import build_parser, main
from hercs.apps.launch.resume_check import CannotResume, plan_resume, set_aside_for_restart
from hercs.run.metrics import recorded_epochs
from hercs.run.rundir import RunDir
from tests.run_dirs import make_run


def snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    """Every path under `folder` with its size and modification time (ns)."""
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*"))}


def cut_metrics_mid_row(run: Path) -> None:
    path = RunDir(run).metrics
    text = path.read_bytes()
    path.write_bytes(text[:-7])  # the last row loses its end


def drop_middle_row(run: Path) -> None:
    path = RunDir(run).metrics
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:2] + lines[3:]))


def repeat_last_row(run: Path) -> None:
    path = RunDir(run).metrics
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join([*lines, lines[-1]]))


def corrupt_latest(run: Path) -> None:
    path = RunDir(run).checkpoint("latest")
    path.write_bytes(path.read_bytes()[:100])  # a copy cut short


REFUSED = {
    # (epochs, trained, checkpoint, damage): what the message must say
    "no-checkpoint": ((4, 2, None, None),
                      "no learner checkpoint ({run}/checkpoints/learner.pt does not exist) to "
                      "continue from, but metrics.csv records epochs 1..2 of 4: resuming would "
                      "train the run from epoch 1 again over those results"),
    "rows-past-the-checkpoint": ((4, 3, 2, None),
                                 "metrics.csv records epochs up to 3, but the learner "
                                 "checkpoint ({run}/checkpoints/learner.pt) is of epoch 2: "
                                 "resuming would train epochs 3 again over their rows"),
    "metrics-cut-mid-row": ((4, 2, 2, cut_metrics_mid_row),
                            "{run}/metrics.csv: cut short: its last line has no line end"),
    "metrics-row-lost": ((4, 3, 3, drop_middle_row),
                         "metrics.csv lacks the rows of epochs 2, which the learner checkpoint "
                         "({run}/checkpoints/learner.pt, epoch 3) says were evaluated"),
    "metrics-two-writers": ((4, 2, 2, repeat_last_row),
                            "{run}/metrics.csv: epochs 2 recorded more than once (two runs "
                            "wrote into this folder at the same time?)"),
    "latest-corrupt": ((4, 2, 2, corrupt_latest),
                       "{run}/checkpoints/learner.pt: not a readable learner checkpoint"),
}
REMEDY = ("Nothing was started or changed. To train this run again from epoch 1, add --restart "
          "(the old metrics.csv, checkpoints/ and episode log are moved to {run}/previous/"
          "<time>/, not deleted); or start a new run with its config: hercs up --config "
          "{run}/config.yaml --run NEW_NAME")


@pytest.mark.parametrize("case", list(REFUSED), ids=list(REFUSED))
def test_a_run_that_cannot_continue_whole_is_refused_and_left_as_it_was(
        tmp_path: Path, case: str, capsys) -> None:
    (epochs, trained, checkpoint, damage), said = REFUSED[case]
    run = tmp_path / "runs" / "r"
    make_run(run, epochs=epochs, trained=trained, checkpoint=checkpoint)
    if damage is not None:
        damage(run)
    before = snapshot(run)
    with pytest.raises(CannotResume) as refused:
        plan_resume(run, epochs=epochs)
    assert said.format(run=run) in str(refused.value)
    assert REMEDY.format(run=run) in str(refused.value)

    assert main(["up", "--resume", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hercs up: ") and said.format(run=run) in err, err
    assert snapshot(run) == before, "a refused resume changed the run directory"


def test_a_finished_run_says_so_and_starts_nothing(tmp_path: Path, capsys) -> None:
    run = tmp_path / "runs" / "done"
    make_run(run, epochs=3, trained=3, checkpoint=3)
    before = snapshot(run)
    plan = plan_resume(run, epochs=3)
    assert plan.finished and plan.checkpoint_epoch == 3
    assert main(["up", "--resume", str(run)]) == 0
    captured = capsys.readouterr()
    assert captured.out == ("hercs up: run done already finished (3 epochs); nothing to do (to "
                            "train it longer: --epochs N with N > 3)\n")
    assert captured.err == ""
    assert snapshot(run) == before  # no process, no log, no config rewritten
    # asked for more epochs, the same folder continues from its checkpoint
    assert not plan_resume(run, epochs=5).finished


def test_a_finished_run_resumed_with_settings_says_they_are_not_applied(
        tmp_path: Path, capsys) -> None:
    """`--set` (and --actors) given to the resume of a finished run: it says that nothing of
    them is applied, naming each, and still starts nothing."""
    run = tmp_path / "runs" / "done"
    make_run(run, epochs=3, trained=3, checkpoint=3)
    before = snapshot(run)
    assert main(["up", "--resume", str(run), "--set", "ddpg.lr_actor=0.0005",
                 "--actors", "4"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("hercs up: run done already finished (3 epochs)")
    assert out[1].startswith("hercs up: not applied, since nothing runs (its config.yaml is "
                             "kept): ")
    assert sorted(out[1].split(": ", 2)[2].split("; ")) == [
        "actor.num_actors: 1 -> 4", "ddpg.lr_actor: 0.001 -> 0.0005"], out
    assert len(out) == 2 and snapshot(run) == before


def test_a_copy_of_a_finished_run_without_checkpoints_is_finished_not_retrained(
        tmp_path: Path, capsys) -> None:
    """What docs/results/runs/<run>/ holds: config.yaml and all of metrics.csv, no
    checkpoint. Nothing to do; asked for more epochs, it is refused (no checkpoint)."""
    run = tmp_path / "runs" / "copy"
    make_run(run, epochs=3, trained=3, checkpoint=None)
    before = snapshot(run)
    assert main(["up", "--resume", str(run)]) == 0
    assert capsys.readouterr().out == (
        "hercs up: run copy already finished (3 epochs); nothing to do (it keeps no learner "
        "checkpoint, so it cannot be trained longer)\n")
    assert main(["up", "--resume", str(run), "--epochs", "5"]) == 2
    assert "metrics.csv records epochs 1..3 of 5" in capsys.readouterr().err
    assert snapshot(run) == before


@pytest.mark.parametrize(("trained", "checkpoint", "unevaluated", "resumes_from"), [
    (0, None, (), 0),        # stopped before its first epoch ended: nothing to lose
    (2, 2, (), 2),           # the common case
    (2, 2, (2,), 2),         # epoch 2's evaluation still pending: asked again on resume
    (3, 3, (3,), 3),         # every epoch trained, the last not yet evaluated: not finished
], ids=["nothing-yet", "rows-through-the-checkpoint", "last-row-pending",
        "all-trained-last-pending"])
def test_a_run_whose_files_agree_continues_from_its_checkpoint(
        tmp_path: Path, trained: int, checkpoint: int | None, unevaluated: tuple[int, ...],
        resumes_from: int) -> None:
    run = tmp_path / "r"
    make_run(run, epochs=3, trained=trained, checkpoint=checkpoint, unevaluated=unevaluated)
    plan = plan_resume(run, epochs=3)
    assert (plan.finished, plan.checkpoint_epoch) == (False, resumes_from)


def test_restart_sets_the_old_files_aside_and_keeps_config_and_logs(tmp_path: Path) -> None:
    run = tmp_path / "r"
    make_run(run, epochs=4, trained=2, checkpoint=None)
    RunDir(run).episode_log.write_bytes(b"old episodes")
    RunDir(run).logs.mkdir()
    (RunDir(run).log("learner-0")).write_text("old log\n")
    metrics_before = RunDir(run).metrics.read_bytes()
    aside = set_aside_for_restart(run)
    assert aside is not None and aside.parent == RunDir(run).previous
    assert sorted(p.name for p in run.iterdir()) == ["config.yaml", "logs", "previous"]
    assert sorted(p.name for p in aside.iterdir()) == ["config.yaml", "episodes.mcap",
                                                       "metrics.csv"]
    assert RunDir(aside).metrics.read_bytes() == metrics_before
    assert recorded_epochs(RunDir(aside).metrics) == [1, 2]
    assert (RunDir(run).log("learner-0")).read_text() == "old log\n"
    # a second restart gets its own folder; the first stays
    RunDir(run).metrics.write_text("epoch\n1\n")
    again = set_aside_for_restart(run)
    assert again is not None and again != aside and RunDir(aside).metrics.exists()
    assert set_aside_for_restart(run) is None  # nothing left to move


def test_the_advice_for_a_damaged_checkpoint_is_a_flag_that_lets_the_run_start(
        tmp_path: Path) -> None:
    """Following the message must work: moving only learner.pt away (what it once said)
    leads to the next refusal (rows without a checkpoint); the flag it names is one
    `hercs up` takes, and after what that flag does the check lets the run start."""
    run = tmp_path / "runs" / "r"
    make_run(run, epochs=4, trained=2, checkpoint=2)
    corrupt_latest(run)
    with pytest.raises(CannotResume) as refused:
        plan_resume(run, epochs=4)
    said = str(refused.value)
    assert "move it away" not in said
    (flag,) = re.findall(r"add (--[a-z-]+)", said)
    assert flag == "--restart"
    assert build_parser()[0].parse_args(["up", "--resume", str(run), flag]).restart
    assert set_aside_for_restart(run) is not None  # what `hercs up --resume RUN --restart` does
    plan = plan_resume(run, epochs=4)
    assert (plan.checkpoint_epoch, plan.recorded, plan.finished) == (0, 0, False)


def test_restart_needs_resume(capsys) -> None:
    assert main(["up", "--restart"]) == 2
    assert "--restart starts a run over in its folder: give it with --resume RUN_DIR" in \
        capsys.readouterr().err


def test_the_learner_sets_rows_past_its_checkpoint_aside(tmp_path: Path) -> None:
    """Defence in depth, when services run without `hercs up`: a learner that finds rows past
    its checkpoint keeps the old file whole in previous/<time>/ and trains those epochs
    again; without a checkpoint it sets every row aside the same way."""
    from hercs.learner.builder import LearnerBuilder
    from hercs.learner.ddpg import DDPGLearner
    from hercs.learner.evaluations import EvalRequests
    from hercs.learner.resume import resume_learner_state
    from hercs.wire.served import ReplayCounters

    for checkpoint, kept in ((2, [1, 2]), (None, [])):
        run = tmp_path / f"r{checkpoint}"
        config = make_run(run, epochs=4, trained=3, checkpoint=checkpoint)
        learner = DDPGLearner(spec=config.task.spec, config=config.ddpg, seed=0)
        loop = LearnerBuilder(config).loop(
            learner, replay_status=lambda samples: ReplayCounters(samples=samples))
        resumed = resume_learner_state(RunDir(run).checkpoints, RunDir(run).metrics,
                                       learner=learner, loop=loop,
                                       eval_requests=EvalRequests(resend_s=60.0))
        assert resumed == checkpoint
        assert recorded_epochs(RunDir(run).metrics) == kept
        (aside,) = RunDir(run).previous.iterdir()
        assert recorded_epochs(RunDir(aside).metrics) == [1, 2, 3]
        assert os.listdir(aside) == ["metrics.csv"]


@pytest.mark.parametrize("how", ["copied", "renamed"])
def test_a_copied_or_renamed_run_folder_is_refused_before_anything_is_written(
        tmp_path: Path, how: str, capsys: pytest.CaptureFixture[str]) -> None:
    """The folder's name is the run's name: a copy or a rename would resume under a name
    its episode log and keys do not have (the replay then crash-looped). `hercs up --resume`
    refuses it with both names and what to do, and its config.yaml is not rewritten."""
    import shutil

    original = tmp_path / "runs" / "b1"
    make_run(original, epochs=3, trained=1, checkpoint=1)
    other = tmp_path / "runs" / "b1-lineb"
    if how == "copied":
        shutil.copytree(original, other)
    else:
        original.rename(other)
    before = snapshot(other)
    with pytest.raises(CannotResume, match=r"holds run 'b1'.*named 'b1-lineb'"):
        plan_resume(other, epochs=3)
    assert main(["up", "--resume", str(other)]) == 2
    err = capsys.readouterr().err
    assert "holds run 'b1'" in err and "--run NEW_NAME" in err and "mv " in err
    assert snapshot(other) == before, "nothing in the folder changed, config.yaml included"


def test_a_renamed_finished_run_is_still_finished(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """A committed run renamed after it finished (the lag-7 runs' folders) starts nothing
    when resumed: it says it is finished, as before, rather than refusing the name."""
    run = tmp_path / "runs" / "push-her-s1"
    make_run(run, epochs=2, trained=2, checkpoint=None)
    renamed = run.rename(tmp_path / "runs" / "push-her-lag7-s1")
    assert main(["up", "--resume", str(renamed)]) == 0
    assert "already finished (2 epochs)" in capsys.readouterr().out
