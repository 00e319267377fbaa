"""What a resumed run's files hold, read as its services will read them and held against the
config it resumes with, before anything starts (hercs/apps/launch/resume_check.py says what
to do about it).

The learner's `learner.pt` is loaded into a learner of the run's config (on the CPU) and
`best.pt` read as `hercs eval` reads it, with the success rate the learner keeps; the episode
log's segments must be the run's and its task's, its newest replay state one the replay can
start from, and its episodes the task's shapes and finite (read in bounded time,
`hercs.run.runlog.survey`). Each refusal names the file and what is wrong; nothing is written.
Epoch-N policy files are not read: nothing reads them on resume.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from hercs.config import HercsConfig
from hercs.errors import ConfigError, InvalidMessage
from hercs.run.checkpoint_file import CheckpointError
from hercs.run.rundir import RunDir
from hercs.run.runlog import EpisodeLog, EpisodeLogError, LogSurvey, read_head, survey_log

if TYPE_CHECKING:
    from hercs.learner.ddpg import DDPGLearner


def check_learner_state(state: dict[str, Any], config: HercsConfig, path: Path) -> None:
    """`learner.pt`'s `state` loads into a fresh learner, loop and evaluation requests of
    `config` as `hercs.learner.resume.resume_learner_state` loads it, holds only finite
    numbers, and was written by this run; else `CheckpointError` naming `path`."""
    import torch

    from hercs.learner.builder import LearnerBuilder
    from hercs.learner.ddpg import DDPGLearner
    from hercs.learner.divergence import nonfinite_tensors, state_tensors

    _same_run(state.get("config"), config, path)
    learner = DDPGLearner(spec=config.task.spec, config=config.ddpg, seed=config.run.seed)
    parts = LearnerBuilder(config)
    loop = parts.loop(learner, replay_status=_never_asked)
    try:
        learner.load_state_dict(state["learner"])
        _optimiser_shapes(learner)
        loop.load_state_dict(state["loop"])
        requests = state["eval_requests"]
        if not all(isinstance(raw, bytes) for raw in requests.values()):
            raise TypeError("eval_requests holds weights that are not bytes")
        parts.eval_requests().load_state_dict(
            requests, pending=loop.pending)
        rng = state["torch_rng"]
        if not (isinstance(rng, torch.Tensor) and rng.dtype == torch.uint8
                and rng.shape == torch.get_rng_state().shape):
            raise TypeError("torch_rng is not a torch generator's state")
    except (KeyError, TypeError, ValueError, AttributeError, RuntimeError) as exc:
        raise CheckpointError(f"{path}: its learner state does not load into this run's "
                              f"learner ({type(exc).__name__}: {_first_line(exc)}); the "
                              "learner would fail on it at every restart") from None
    bad = nonfinite_tensors(state_tensors(state["learner"], "learner"))
    if bad:
        raise CheckpointError(f"{path}: its learner state holds numbers that are not finite "
                              f"({'; '.join(bad)}), which the learner would train on")


def _optimiser_shapes(learner: DDPGLearner) -> None:
    """Adam's moments of the shape of their parameters (torch loads any shape: the first
    update would fail)."""
    import torch

    for optimiser in (learner.actor_optim, learner.critic_optim):
        for group in optimiser.param_groups:
            for param in group["params"]:
                for name, value in optimiser.state.get(param, {}).items():
                    if (isinstance(value, torch.Tensor) and value.dim()
                            and value.shape != param.shape):
                        raise ValueError(f"an optimiser's {name} has shape "
                                         f"{tuple(value.shape)}, its parameter "
                                         f"{tuple(param.shape)}")


def check_best_policy(run_dir: Path, config: HercsConfig) -> None:
    """`best.pt`, if there is one, holds a policy of this run's task that loads (as `hercs
    eval` reads it) and the success rate the learner keeps to beat (`learner_shell`); else
    `CheckpointError` (or `ConfigError`) naming it."""
    from hercs.learner.checkpoint import load_policy_file
    from hercs.run.policy_files import read_policy

    path = RunDir(run_dir).checkpoint("best")
    try:
        state = load_policy_file(path)
        if state is None:
            return
        loaded = read_policy(run_dir, "best")
        _same_run(loaded.config.to_dict(), config, path)
        success = state.get("success_rate")
        if not (isinstance(success, float | int) and math.isfinite(success)
                and 0 <= success <= 1):
            raise CheckpointError(f"{path}: its success_rate is {success!r}, not a number in "
                                  "[0, 1]")
    except (CheckpointError, ConfigError) as exc:
        raise type(exc)(f"{exc}. It is the run's best policy so far, which the learner reads "
                        "as it starts (its success rate is the one to beat) and `hercs eval` "
                        "reads after; moved out of the folder, the run continues without it "
                        "(the next better evaluation writes a new one)") from None


def _same_run(saved: Any, config: HercsConfig, path: Path) -> None:
    """A checkpoint's embedded config names this run and its task (if it names any)."""
    if not isinstance(saved, dict):
        return
    run = (saved.get("run") or {}).get("name") if isinstance(saved.get("run"), dict) else None
    task = (saved.get("task") or {}).get("name") if isinstance(saved.get("task"), dict) else None
    if (run and run != config.run.name) or (task and task != config.task.name):
        raise CheckpointError(
            f"{path} was written by run {run!r} of task {task!r}, but this folder holds run "
            f"{config.run.name!r} of task {config.task.name!r} (its config.yaml): files of "
            "two runs are mixed (a copied folder whose config.yaml was edited keeps the old "
            "run's checkpoints)")


def check_episode_log(run_dir: Path, config: HercsConfig) -> LogSurvey:
    """The log's segments are this run's and task's, its newest replay state fits the replay
    of `config`, and its episodes are the task's (`survey_log`: raises `BadEpisode`); what
    the read found (torn tails, what it left unread). `EpisodeLogError` names the file."""
    spec = config.task.spec
    segments = EpisodeLog.check(run_dir, run=config.run.name, task=spec.name)
    for path in reversed(segments):
        _, state = read_head(path)
        if state is not None:
            _check_replay_state(state, config, path)
            break
    return survey_log(segments, spec=spec)


def _check_replay_state(msg: Any, config: HercsConfig, path: Path) -> None:
    """The replay state a restarted replay starts from (`ReplayTable.recover`) decodes, has
    normalisers and failed goals of the task's sizes, and keeps a buffer of this run's."""
    from hercs.rl.normalizer import checked_state
    from hercs.wire.codec import msg_to_replay_state

    spec = config.task.spec
    try:
        state = msg_to_replay_state(msg)
        checked_state(state.o_stats, spec.obs_dim)
        checked_state(state.g_stats, spec.goal_dim)
        goals = state.recent_failed_goals
        if goals.size and (goals.ndim != 2 or goals.shape[1] != spec.goal_dim):
            raise ValueError(f"its failed goals have shape {goals.shape}, the task's goals "
                             f"({spec.goal_dim},)")
    except (InvalidMessage, ValueError) as exc:
        raise EpisodeLogError(f"{path}: its replay state (what a restarted replay starts "
                              f"from) does not fit task {spec.name}: {exc}") from None
    kept = state.next_episode_id - state.first_held_id
    if kept < min(state.next_episode_id, config.capacity_episodes):
        raise EpisodeLogError(
            f"{path}: its replay state keeps the {kept} episodes from id "
            f"{state.first_held_id} on, fewer than this run's buffer of "
            f"{config.capacity_episodes} (replay.buffer_transitions="
            f"{config.replay.buffer_transitions}) holds: it was written with a smaller buffer")


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [""])[0]


def _never_asked(samples: int) -> NoReturn:
    """A checked checkpoint's loop only loads its state: it never ends an epoch."""
    raise AssertionError(f"a checkpoint check asked the replay's status ({samples} samples)")
