"""A learner's state across restarts: what its checkpoint holds and how a restarted learner
continues from it, with the run's metrics.csv made to agree.

With `checkpoints/learner.pt` the learner continues from the end of its epoch, and a pending
epoch that already has its row is not evaluated again; rows of later epochs (only after a
failed checkpoint write, or a file put back by hand) are set aside (the old file to
`previous/<time>/metrics.csv`), never deleted, and trained again. Without one it starts at
epoch 0, setting rows aside the same way. `hercs up --resume` refuses such a folder before
anything starts; this is the learner's own guard, for services started without `hercs up`.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import torch

from hercs.errors import Diverged
from hercs.learner.checkpoint import load_checkpoint, save_checkpoint
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.divergence import nonfinite_tensors, state_tensors
from hercs.learner.evaluations import EvalRequests
from hercs.learner.loop import LearnerLoop
from hercs.run.metrics import recorded_epochs, truncate_metrics
from hercs.run.rundir import LATEST, aside_folder

log = logging.getLogger("hercs.learner")


def save_learner_state(checkpoints: Path, *, learner: DDPGLearner, loop: LearnerLoop,
                       eval_requests: EvalRequests, config_record: dict[str, Any]) -> bool:
    """Write `checkpoints/learner.pt` (with `config_record`, the run's resolved config as a
    dict); False if the write failed (logged, the previous file
    kept). A learner state holding a NaN or an inf anywhere (weights, targets, Adam's moments,
    normalisers) raises `Diverged` instead and leaves the previous checkpoint as it was: a
    resumed run must never start from numbers it cannot train on. (Adam's second moment can
    overflow to inf while the weights stay finite: that weight then never moves again.)"""
    state: dict[str, Any] = {
        "learner": learner.state_dict(), "loop": loop.state_dict(),
        "torch_rng": torch.get_rng_state(), "eval_requests": eval_requests.state_dict(),
        "config": config_record}
    bad = nonfinite_tensors(state_tensors(state["learner"], "learner"))
    if bad:
        raise Diverged(f"{checkpoints / LATEST} not written, the one there is kept: "
                       f"{'; '.join(bad)}")
    return save_checkpoint(checkpoints, state)


def resume_learner_state(checkpoints: Path, metrics_path: Path, *, learner: DDPGLearner,
                         loop: LearnerLoop, eval_requests: EvalRequests) -> int | None:
    """Load the checkpoint into `learner`, `loop` and `eval_requests` and make metrics.csv end
    at it (later rows set aside); the epoch resumed from, or None (no checkpoint: a fresh
    start)."""
    aside = aside_folder(metrics_path.parent)
    state = load_checkpoint(checkpoints)
    if state is None:
        dropped = truncate_metrics(metrics_path, through_epoch=0, aside=aside)
        if dropped:
            log.warning("no checkpoint: training from epoch 1; metrics.csv held rows of epochs "
                        "%s, set aside in %s (the file as it was)", dropped,
                        aside / metrics_path.name)
        return None
    learner.load_state_dict(state["learner"])
    loop.load_state_dict(state["loop"])
    torch.set_rng_state(state["torch_rng"])
    epoch = loop.epoch
    dropped = truncate_metrics(metrics_path, through_epoch=epoch, aside=aside)
    recorded = set(recorded_epochs(metrics_path))
    for pending in [e for e in loop.pending if e in recorded]:
        del loop.pending[pending]  # its row was written after the checkpoint
    eval_requests.load_state_dict(state["eval_requests"], pending=loop.pending)
    log.info("resumed from the checkpoint of epoch %d (weights version %d, %d updates)%s%s",
             epoch, loop.version, learner.updates,
             f"; metrics rows of epochs {dropped} set aside in {aside / metrics_path.name} "
             "(trained again)" if dropped else "",
             f"; epochs {sorted(loop.pending)} still to be evaluated" if loop.pending else "")
    return epoch
