"""`hercs up --resume` reads every file a service would fail on before anything changes (issue
57, item 3): a crafted best.pt, a copied folder whose config.yaml was edited to its new name,
an episode log with a NaN or a wrong-shaped row, a learner or replay state of another config
are each refused with exit 2, the cause named, the folder byte for byte as it was; a torn
tail is said on the terminal with the episodes it cut. Real run folders
(`tests/run_dirs.make_run`: a learner's real checkpoint), real MCAP logs written by the
replay's writer, real torch files."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides
from hercs.learner.checkpoint import save_checkpoint, save_policy
from hercs.learner.ddpg import DDPGLearner
from hercs.proto import hercs_pb2 as pb
from hercs.rl.normalizer import Normalizer
from hercs.rl.task_registry import task_spec
from hercs.run.checkpoint_file import read_checkpoint_file
from hercs.run.rundir import RunDir
from hercs.run.runlog import BadEpisode, EpisodeLogWriter, survey_log
from hercs.wire.codec import array_to_msg, episode_to_msg, replay_state_to_msg, weights_to_msg
from hercs.wire.replay_state import ReplayState
from tests.integration.launcher_standins import Launcher
from tests.run_dirs import make_run
from tests.support import free_endpoint

pytestmark = pytest.mark.integration

COMMAND_TIMEOUT_S = 120


def episodes(config: HercsConfig, ids: range) -> list[tuple[int, pb.Episode]]:
    spec, rng = config.task.spec, np.random.default_rng(ids.start)
    return [(i, episode_to_msg(random_episode(spec, rng, seq=i), run=config.run.name,
                               task=spec.name)) for i in ids]


def write_segment(path: Path, config: HercsConfig, logged: list[tuple[int, pb.Episode]], *,
                  group: int = 4, close: bool = True, state: pb.ReplayState | None = None
                  ) -> None:
    """`logged` appended as the replay appends them (group commits of `group`), then closed,
    or left as a killed replay leaves its file."""
    writer = EpisodeLogWriter(path, run=config.run.name, task=config.task.spec.name,
                              scene=False, spec=config.task.spec)
    if state is not None:
        writer.append_replay_state(state)
    for start in range(0, len(logged), group):
        writer.append_many(logged[start:start + group])
    if close:
        writer.close()


def with_log(run_dir: Path, config: HercsConfig, *, bad: pb.Episode | None = None,
             state: pb.ReplayState | None = None) -> Path:
    """Two segments, as a replay restarted once leaves them: episodes.000.mcap (ids 0-15; id
    12 replaced by `bad`) and episodes.mcap (16-23, after `state` if given, as a bounded log
    starts a segment). Returns the numbered one."""
    files = RunDir(run_dir)
    first = episodes(config, range(16))
    if bad is not None:
        first[12] = (12, bad)
    write_segment(files.episode_log, config, first)
    numbered = files.next_segment()
    files.episode_log.rename(numbered)
    write_segment(files.episode_log, config, episodes(config, range(16, 24)), state=state)
    return numbered


def folder_bytes(folder: Path) -> dict[str, bytes | None]:
    """Every path under `folder` with its bytes (None: a folder)."""
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else None
            for p in sorted(folder.rglob("*"))}


def resume(run_dir: Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hercs.apps.cli", "up", "--resume",
                           str(run_dir)], cwd=cwd, capture_output=True, text=True,
                          timeout=COMMAND_TIMEOUT_S)


def refused_unchanged(run_dir: Path, cwd: Path) -> str:
    """Resume `run_dir`: exit 2 and every byte of the folder as it was; its stderr."""
    before = folder_bytes(run_dir)
    done = resume(run_dir, cwd)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    assert "Nothing was started or changed" in done.stderr, done.stderr
    assert folder_bytes(run_dir) == before, "a refused resume changed the run folder"
    return done.stderr


@pytest.fixture
def run(tmp_path: Path) -> tuple[Path, HercsConfig]:
    """A run stopped in epoch 3 of 4: a real learner checkpoint of epoch 2, its rows, and an
    episode log of 24 episodes in two segments."""
    folder = tmp_path / "runs" / "base"
    config = make_run(folder, epochs=4, trained=2, checkpoint=2)
    with_log(folder, config)
    return folder, config


def other_task_policy(config: HercsConfig) -> bytes:
    """A real policy's `Weights`, of FetchPush's shapes (25-d observations, not Reach's 10)."""
    learner = DDPGLearner(spec=task_spec("push"), config=config.ddpg, seed=0)
    weights = learner.policy_weights(1)
    return weights_to_msg(version=1, actor_params=weights.actor, o_stats=weights.o_stats,
                          g_stats=weights.g_stats, epoch=2, evaluate=True).SerializeToString()


@pytest.mark.parametrize("crafted", ["no-expected-keys", "wrong-shaped-policy"])
def test_a_crafted_best_policy_is_refused_before_anything_changes(
        run: tuple[Path, HercsConfig], tmp_path: Path, crafted: str) -> None:
    """Before, the learner read it after start: 6 crashes, exit 1, the log rolled to a new
    segment and config.yaml rewritten."""
    run_dir, config = run
    best = RunDir(run_dir).checkpoint("best")
    if crafted == "no-expected-keys":
        torch.save({"weights": torch.zeros(3), "epoch": 2}, best)
        said = "not a policy file of this version of hercs (no 'policy')"
    else:
        save_policy(best.parent, best.name, weights=other_task_policy(config), epoch=2,
                    success_rate=0.5, config=config.to_dict())
        said = "the policy in it does not fit task reach"
    err = refused_unchanged(run_dir, tmp_path)
    assert err.startswith(f"hercs up: {best}: {said}"), err
    assert "It is the run's best policy so far" in err and "add --restart" in err, err


def replay_state(obs_dim: int) -> pb.ReplayState:
    """The state a replay of 16 episodes saves, its observation normaliser `obs_dim` wide."""
    return replay_state_to_msg(ReplayState(
        next_episode_id=16, first_held_id=0, failures=16,
        recent_failed_goals=np.zeros((0, 3), np.float32),
        o_stats=Normalizer(obs_dim).state_dict(), g_stats=Normalizer(3).state_dict(),
        cluster_model=None))


@pytest.mark.parametrize("state", ["learner-checkpoint", "replay-state"])
def test_a_saved_state_that_does_not_fit_the_runs_services_is_refused(
        tmp_path: Path, state: str) -> None:
    """A learner.pt of another network size, a log whose replay state has another task's
    normaliser: each loads only into services of another config, so the learner or the
    replay would fail on it at every restart."""
    run_dir = tmp_path / "runs" / "base"
    config = make_run(run_dir, epochs=4, trained=2, checkpoint=2)
    if state == "learner-checkpoint":  # epoch 2's checkpoint, its networks 32 wide, not 16
        latest = RunDir(run_dir).checkpoint("latest")
        saved = read_checkpoint_file(latest, what="learner checkpoint")
        wider = apply_overrides(config, ["ddpg.hidden_size=32"]).ddpg
        saved["learner"] = DDPGLearner(spec=config.task.spec, config=wider, seed=0).state_dict()
        assert save_checkpoint(latest.parent, saved)
        with_log(run_dir, config)
        said = (f"{RunDir(run_dir).checkpoint('latest')}: its learner state does not load "
                "into this run's learner (RuntimeError: Error(s) in loading state_dict")
    else:
        with_log(run_dir, config, state=replay_state(obs_dim=25))
        said = (f"{RunDir(run_dir).episode_log}: its replay state (what a restarted replay "
                "starts from) does not fit task reach: Normalizer.load_state_dict: 'sum' has "
                "shape (25,), expected (10,)")
    err = refused_unchanged(run_dir, tmp_path)
    assert err.startswith(f"hercs up: {said}"), err


@pytest.mark.parametrize("checkpoint", [True, False], ids=["with-checkpoint", "log-only"])
def test_a_copied_folder_with_its_config_edited_to_the_new_name_is_refused(
        tmp_path: Path, checkpoint: bool) -> None:
    """`cp -r base base2` and `run.name: base2` in base2's config.yaml: the folder's name
    check passes, but its learner checkpoint and episode log were written for run 'base'.
    Before, the replay then failed 6 times with "written for run 'base'"."""
    base = tmp_path / "runs" / "base"
    config = make_run(base, epochs=4, trained=2 if checkpoint else 0,
                      checkpoint=2 if checkpoint else None)
    with_log(base, config)
    copy = base.with_name("base2")
    shutil.copytree(base, copy)
    saved = RunDir(copy).config
    saved.write_text(saved.read_text().replace("name: base\n", "name: base2\n"))
    assert "name: base2\n" in saved.read_text()
    err = refused_unchanged(copy, tmp_path)
    if checkpoint:  # the first file read: the learner's checkpoint
        assert err.startswith(f"hercs up: {RunDir(copy).checkpoint('latest')} was written by "
                              "run 'base' of task 'reach', but this folder holds run 'base2'"), err
    else:
        assert err.startswith(f"hercs up: {RunDir(copy).log_segments()[0]} was written for "
                              "run 'base' task 'reach'; this replay serves run 'base2'"), err


@pytest.mark.parametrize("row", ["nan-observation", "wrong-shaped-actions"])
def test_an_episode_log_with_a_bad_row_is_refused_naming_segment_episode_and_fault(
        tmp_path: Path, row: str) -> None:
    """Before: NaN observations were accepted (the learner then skipped ~7,500 bad batches a
    minute in silence); a wrong-shaped action stopped the run with "refused the run's
    configuration", which is not the cause."""
    run_dir = tmp_path / "runs" / "base"
    config = make_run(run_dir, epochs=4, trained=2, checkpoint=2)
    _, bad = episodes(config, range(12, 13))[0]
    if row == "nan-observation":
        obs = np.zeros((51, 10), np.float32)
        obs[3, 5] = np.nan
        array_to_msg(obs, out=bad.obs)
        said = ("episode 12's obs hold nan at step 3, index 5: not a finite number; the replay "
                "would store it and every batch drawn from it would carry that value")
    else:
        array_to_msg(np.zeros((50, 3), np.float32), out=bad.actions)
        said = ("episode 12's actions have shape (50, 3), the task's are (50, 4) (task reach: "
                "obs_dim 10, goal_dim 3, action_dim 4, episode_steps 50); the replay cannot "
                "store it as one of the task's and would stop the run")
    segment = with_log(run_dir, config, bad=bad)
    err = refused_unchanged(run_dir, tmp_path)
    assert err.startswith(f"hercs up: {segment}: {said}"), err
    assert "refused the run's configuration" not in err


def test_a_torn_tail_is_said_on_the_terminal_with_the_episodes_it_cut(tmp_path: Path) -> None:
    """A replay killed mid-append leaves a chunk cut short; before, only replay-0.log said
    so. The pre-check reads the cut record's head: the 4 episodes of its group commit."""
    run_dir = tmp_path / "runs" / "torn"
    config = make_run(run_dir, epochs=3, trained=2, checkpoint=2)
    log = RunDir(run_dir).episode_log
    write_segment(log, config, episodes(config, range(40)), close=False)
    data = log.read_bytes()
    log.write_bytes(data[:len(data) - 3000])  # inside the last chunk (4 episodes, ~17 KB)
    launcher = Launcher([sys.executable, "-m", "hercs.apps.cli", "up", "--resume",
                         str(run_dir), "--listen", free_endpoint()], cwd=tmp_path)
    try:
        line = launcher.wait_for_line(r"ends in a torn tail", timeout_s=COMMAND_TIMEOUT_S)
        assert line.startswith(f"hercs up: {log} ends in a torn tail ("), line
        assert ("the cut record held 4 episodes (ids 36-39), which the run no longer has, and "
                "every episode up to id 35 is whole") in line, line
        launcher.wait_for_line(r"resuming run torn", timeout_s=COMMAND_TIMEOUT_S)
        launcher.proc.send_signal(signal.SIGINT)
        assert launcher.finish(timeout_s=COMMAND_TIMEOUT_S) == 128 + signal.SIGINT
    finally:
        launcher.kill()
    assert line in launcher.out, "said on stdout, with the run's other lines"


def test_a_log_past_the_budget_is_read_at_both_ends_of_each_segment_and_says_what_it_left(
        tmp_path: Path) -> None:
    """With no budget beyond the ends (one chunk each here), the first and last 4 episodes
    of each segment are read and checked, and the note names the ids left unread; a bad row
    in a segment's last chunk is found all the same."""
    run_dir = tmp_path / "runs" / "big"
    config = make_run(run_dir, epochs=4, trained=0, checkpoint=None)
    numbered = with_log(run_dir, config)
    segments = RunDir(run_dir).log_segments()
    survey = survey_log(segments, spec=config.task.spec, budget_bytes=0, end_bytes=1)
    assert survey.checked == 16 and not survey.torn
    assert [(u.segment, u.episodes, u.after, u.before) for u in survey.unread] == [
        (numbered, 8, 3, 12)], survey.unread  # the live segment: 2 chunks, both ends
    (note,) = survey.notes()
    assert ("the episode log was checked in part: 16 episodes read and checked, 8 left unread "
            f"(ids 4-11 of {numbered.name}), past the pre-check's budget of 0 bytes") in note
    whole = survey_log(segments, spec=config.task.spec, budget_bytes=4 * 2**20, end_bytes=1)
    assert whole.checked == 24 and not whole.unread and not whole.notes()

    bad_dir = tmp_path / "runs" / "bad"
    make_run(bad_dir, epochs=4, trained=0, checkpoint=None)
    _, bad = episodes(config, range(12, 13))[0]
    bad.g.data = np.full((50, 3), np.inf, np.float32).tobytes()
    with_log(bad_dir, config, bad=bad)  # id 12 opens the numbered segment's last chunk
    with pytest.raises(BadEpisode, match=r"episode 12's g hold inf at step 0, index 0"):
        survey_log(RunDir(bad_dir).log_segments(), spec=config.task.spec, budget_bytes=0,
                   end_bytes=1)
