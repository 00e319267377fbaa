"""What `hercs up --resume RUN` finds in a run directory, decided before anything starts:
continue, nothing to do, or refuse, so that a resume never trains over results.

`learner.pt` (epoch C, epochs P awaiting evaluation) and `metrics.csv` (rows R) agree when R
holds exactly the epochs 1..C not in P (perhaps with rows of P written after the checkpoint);
R covering 1..`training.epochs` with C at the end, or with no checkpoint, is a finished run and
nothing starts. Anything else is refused, saying what would work: rows without a checkpoint
would be trained over, rows past it or missing would be trained again or lost.
Past that, every file a service will read is read as it will read it, against the config the
run resumes with (hercs/apps/launch/resume_files.py): a file that would fail the run after it
started is refused here, before anything changes. `--restart` starts over:
`set_aside_for_restart` moves the old files to `previous/<time>/`.
"""

from __future__ import annotations

import dataclasses
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from hercs.apps.launch.resume_files import (
    check_best_policy,
    check_episode_log,
    check_learner_state,
)
from hercs.apps.launch.run_plan import resolve_run
from hercs.apps.tracking.rows import flat_hyperparameters
from hercs.config import HercsConfig, apply_overrides, load_yaml
from hercs.errors import ConfigError, HercsError
from hercs.run.checkpoint_file import CheckpointError
from hercs.run.metrics import MetricsFileError, checked_epochs, epoch_spans
from hercs.run.rundir import (
    CHECKPOINTS,
    CONFIG,
    LOCK,
    LOGS,
    METRICS,
    PREVIOUS,
    ROUTER,
    SLURM,
    RunDir,
    aside_folder,
)
from hercs.run.runlog import BadEpisode, EpisodeLogError

KEPT_ON_RESTART = frozenset({CONFIG, LOGS, SLURM, LOCK, PREVIOUS, ROUTER})
"""What `--restart` leaves in place (config.yaml is also copied aside; logs/ goes on)."""


class CannotResume(HercsError):
    """The run directory's files do not let `--resume` continue without losing results; the
    message says why and what would work."""


@dataclass(frozen=True)
class ResumePlan:
    """A run `--resume` may continue: from `checkpoint_epoch` (0: from the start), or not at
    all when `finished`."""

    checkpoint_epoch: int
    recorded: int
    """Epochs metrics.csv records."""
    finished: bool
    notes: tuple[str, ...] = ()
    """What the files' read found that the user is told before the run starts (a torn tail of
    the episode log, what the read left unread)."""

    def describe(self, name: str) -> str:
        if self.finished:
            epochs = max(self.checkpoint_epoch, self.recorded)
            longer = ("it keeps no learner checkpoint, so it cannot be trained longer" if
                      not self.checkpoint_epoch else
                      f"to train it longer: --epochs N with N > {epochs}")
            return f"run {name} already finished ({epochs} epochs); nothing to do ({longer})"
        if not self.checkpoint_epoch:
            return f"resuming run {name} from its start (no epoch had ended)"
        return f"resuming run {name} from the checkpoint of epoch {self.checkpoint_epoch}"


def _remedy(run_dir: Path) -> str:
    return (f"Nothing was started or changed. To train this run again from epoch 1, add "
            f"--restart (the old {METRICS}, {CHECKPOINTS}/ and episode log are moved to "
            f"{RunDir(run_dir).previous}/<time>/, not deleted); or start a new run with its "
            f"config: hercs up --config {RunDir(run_dir).config} --run NEW_NAME")


def plan_resume(run_dir: Path, *, epochs: int, config: HercsConfig | None = None
                ) -> ResumePlan:
    """Whether and from where `run_dir` can be resumed to `epochs` epochs with `config`
    (default: its config.yaml's, as `hercs up --resume` reads it); raises `CannotResume` when
    its files disagree or one would fail the run (module docstring)."""
    from hercs.learner.checkpoint import load_checkpoint

    files = RunDir(run_dir)
    latest = files.checkpoint("latest")
    try:
        state = load_checkpoint(files.checkpoints)
        checkpoint, pending = _checkpoint_epochs(state, latest)
    except CheckpointError as exc:
        best = (f" (`hercs eval {run_dir} --checkpoint best` still reads the best policy)"
                if files.checkpoint("best").is_file() else "")
        raise CannotResume(f"{exc}. The run cannot continue without it{best}. "
                           f"{_remedy(run_dir)}") from None
    plan = _plan_from(run_dir, state, checkpoint, pending, epochs=epochs)
    if plan.finished:
        return plan
    _check_run_name(run_dir)  # after the checkpoint and metrics: they say more about the run
    config = config or _saved_config(run_dir)
    try:
        if state is not None:
            check_learner_state(state, config, latest)
        check_best_policy(run_dir, config)
        survey = check_episode_log(run_dir, config)  # parsed as MCAP, never unpickled
    except (CheckpointError, ConfigError, BadEpisode) as exc:  # each says what it would do
        raise CannotResume(f"{exc}. {_remedy(run_dir)}") from None
    except EpisodeLogError as exc:
        raise CannotResume(f"{exc}. The replay could not reload its episodes from it. "
                           f"{_remedy(run_dir)}") from None
    return dataclasses.replace(plan, notes=tuple(survey.notes()))


def _saved_config(run_dir: Path) -> HercsConfig:
    """The config `hercs up --resume` reads: config.yaml's, named after the folder."""
    return apply_overrides(load_yaml(RunDir(run_dir).config),
                           [f"run.name={run_dir.resolve().name}",
                            f"run.run_dir={run_dir.resolve().parent}"])


def _check_run_name(run_dir: Path) -> None:
    """A run resumes under the name it was made with, which is its folder's: its episode log
    and checkpoints carry it, and so do its Zenoh keys. A copied or renamed folder (whose
    config.yaml names the old run) is refused here, before anything is written."""
    try:
        saved = yaml.safe_load(RunDir(run_dir).config.read_text()) or {}
    except (OSError, yaml.YAMLError):
        return  # the config's own reader says what is wrong with it
    name = str(((saved.get("run") or {}) if isinstance(saved, dict) else {}).get("name") or "")
    folder = run_dir.resolve().name
    if name and name != folder:
        raise CannotResume(
            f"{run_dir}: this folder holds run {name!r} (its config.yaml, episode log and "
            f"checkpoints were written for that name), but the folder is named {folder!r}: a "
            f"copied or renamed run cannot resume under another name. Resume it under its own "
            f"(`mv {run_dir} {run_dir.resolve().parent / name}`, where no folder of that name "
            f"is, then `hercs up --resume {run_dir.resolve().parent / name}`), or start a new "
            f"run from its settings (`hercs up --config {RunDir(run_dir).config} --run-dir "
            f"{run_dir.resolve().parent} --run NEW_NAME`). Nothing here was changed")


def _plan_from(run_dir: Path, state: dict[str, Any] | None, checkpoint: int,
               pending: set[int], *, epochs: int) -> ResumePlan:
    """`plan_resume`'s reading of metrics.csv against the learner checkpoint `state`."""
    files = RunDir(run_dir)
    latest = files.checkpoint("latest")
    try:
        recorded = checked_epochs(files.metrics)
    except MetricsFileError as exc:
        raise CannotResume(f"{exc}. Which epochs were trained is not known, so the run cannot "
                           f"continue safely; put back a whole copy of {METRICS} and resume "
                           f"again. {_remedy(run_dir)}") from None
    rows = set(recorded)
    last = max(rows, default=0)
    covers = rows >= set(range(1, epochs + 1))
    if state is None:
        if covers:
            return ResumePlan(checkpoint_epoch=0, recorded=len(rows), finished=True)
        if rows:
            raise CannotResume(
                f"{run_dir}: no learner checkpoint ({latest} does not exist) to continue "
                f"from, but {METRICS} records epochs {epoch_spans(recorded)} of {epochs}: resuming "
                f"would train the run from epoch 1 again over those results. "
                f"{_remedy(run_dir)}")
        return ResumePlan(checkpoint_epoch=0, recorded=0, finished=False)
    past = sorted(e for e in rows if e > checkpoint)
    if past:
        raise CannotResume(
            f"{run_dir}: {METRICS} records epochs up to {last}, but the learner checkpoint "
            f"({latest}) is of epoch {checkpoint}: resuming would train epochs "
            f"{epoch_spans(past)} again over their rows (a checkpoint write failed, or files "
            f"from two copies of the run were mixed). {_remedy(run_dir)}")
    missing = sorted(set(range(1, checkpoint + 1)) - rows - pending)
    if missing:
        raise CannotResume(
            f"{run_dir}: {METRICS} lacks the rows of epochs {epoch_spans(missing)}, which the "
            f"learner checkpoint ({latest}, epoch {checkpoint}) says were evaluated and "
            f"written: the file was cut short or replaced; put back a whole copy and resume "
            f"again. {_remedy(run_dir)}")
    finished = checkpoint >= epochs and covers
    return ResumePlan(checkpoint_epoch=checkpoint, recorded=len(rows), finished=finished)


def _checkpoint_epochs(state: dict[str, Any] | None, path: Path) -> tuple[int, set[int]]:
    """The epoch a learner checkpoint was taken at and the epochs it still awaited the
    evaluation of (0 and none without a checkpoint)."""
    if state is None:
        return 0, set()
    try:
        loop = state["loop"]
        return int(loop["epoch"]), {int(e) for e in loop.get("pending", {})}
    except (KeyError, TypeError, AttributeError, ValueError) as exc:  # data, but not ours
        raise CheckpointError(f"{path}: not a learner checkpoint of this version of hercs "
                              f"(its loop state: {type(exc).__name__}: {exc})") from None


def set_aside_for_restart(run_dir: Path) -> Path | None:
    """Move everything the old run made (metrics.csv, checkpoints/, the episode log,
    tensorboard/, …; not config.yaml, logs/ or a Slurm job's files) into a new
    `previous/<time>/`, with a copy of config.yaml; returns that folder (None: nothing to
    move)."""
    moving = sorted(p for p in run_dir.iterdir() if p.name not in KEPT_ON_RESTART)
    if not moving:
        return None
    aside = aside_folder(run_dir)
    aside.mkdir(parents=True)
    config = RunDir(run_dir).config
    if config.is_file():
        shutil.copy2(config, RunDir(aside).config)
    for path in moving:
        path.rename(aside / path.name)
    return aside


UNCOMPARED = ("run.name", "run.run_dir", "transport.connect", "training.epochs")
"""What a resume sets itself (the folder's name and parent, the router's ports) or `describe`
already speaks of (the epochs), left out of `settings_not_applied`."""


def settings_not_applied(run_dir: Path, config: HercsConfig) -> list[str]:
    """The settings `config` (what `hercs up --resume` was given: its --set, --actors,
    --listen, …) changes in `run_dir`'s saved config, as `field: saved -> given`: a finished
    run starts nothing, so none of them is applied."""
    saved = resolve_run(_saved_config(run_dir))
    given = resolve_run(config)
    before = flat_hyperparameters(saved.to_dict())
    after = flat_hyperparameters(given.to_dict())
    return [f"{key}: {before.get(key)} -> {value}" for key, value in after.items()
            if value != before.get(key) and key not in UNCOMPARED]
