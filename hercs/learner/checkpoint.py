"""The learner's checkpoints: written atomically, the last good one kept.

`runs/<run>/checkpoints/learner.pt` holds what a resumed learner needs to continue exactly at
the end of its epoch: the DDPG state, the loop's counters, torch's RNG state, and the `Weights`
of each epoch still awaiting its evaluation (to ask again). A write goes to `learner.pt.tmp`,
is fsynced, then renamed over
`learner.pt` (and the folder fsynced), so a crash or a full disk leaves the previous one whole.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
from pathlib import Path
from typing import Any

import torch

from hercs.run.checkpoint_file import CheckpointError, read_checkpoint_file
from hercs.run.rundir import LATEST  # the run directory's names have one owner

log = logging.getLogger(__name__)

def save_checkpoint(folder: Path, state: dict[str, Any], *, name: str = LATEST) -> bool:
    """Write `state` atomically to `folder/name`; False (logged, the previous file kept) if the
    write failed, e.g. on a full disk."""
    path = folder / name
    tmp = path.with_name(path.name + ".tmp")
    buffer = io.BytesIO()
    torch.save(state, buffer)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tmp.open("wb") as f:
            f.write(buffer.getbuffer())
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        log.error("checkpoint %s not written (%s); the previous one is kept", path, exc)
        with contextlib.suppress(OSError):
            tmp.unlink()
        return False
    return True


def load_checkpoint(folder: Path, *, name: str = LATEST) -> dict[str, Any] | None:
    """The checkpoint in `folder/name`, or None if there is none. A file that does not load,
    or holds more than data, raises `CheckpointError` naming it (a resumed run must not
    silently start over; `hercs up --resume` says what would work)."""
    path = folder / name
    if not path.exists():
        return None
    state = read_checkpoint_file(path, what="learner checkpoint")
    if "learner" not in state or "loop" not in state:
        raise CheckpointError(f"{path}: not a learner checkpoint of this version of hercs (no "
                              "'learner'/'loop' state)")
    return state


def save_policy(folder: Path, name: str, *, weights: bytes, epoch: int, success_rate: float,
                config: dict[str, Any]) -> bool:
    """A policy file: the serialised `Weights` an epoch's evaluation used (actor and
    normalisers), its epoch and success, and the run's config; what `hercs eval` loads."""
    return save_checkpoint(folder, {"policy": bytes(weights), "epoch": int(epoch),
                                    "success_rate": float(success_rate), "config": config},
                           name=name)


def load_policy_file(path: Path) -> dict[str, Any] | None:
    """A `save_policy` file, or None if there is none. A file that does not load raises
    `CheckpointError` naming it."""
    if not path.exists():
        return None
    state = read_checkpoint_file(path, what="policy file")
    if "policy" not in state:
        raise CheckpointError(f"{path}: not a policy file of this version of hercs (no "
                              "'policy')")
    return state
