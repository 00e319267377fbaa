"""Opening a checkpoint file (`best.pt`, `epoch-NNNN.pt`, `learner.pt`) as data, never as code.

`torch.load(weights_only=True)` unpickles with an allow-list, so any other global a file names
is refused before it is called (docs/SECURITY.md, "Files"). `ALLOWED_GLOBALS` adds numpy's
array constructor for `learner.pt`'s float64 normaliser statistics; only a float64 dtype may
be built.
"""

from __future__ import annotations

import pickle
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from hercs.errors import HercsError


class CheckpointError(HercsError):
    """A checkpoint file exists but cannot be used; the message names it and says why."""


_RECONSTRUCT = np.zeros(0).__reduce__()[0]
"""The function numpy pickles an array with (`numpy._core.multiarray._reconstruct`)."""

ALLOWED_GLOBALS: list[Any] = [
    np.ndarray, np.dtype,
    np.dtypes.Float64DType,  # the one dtype an array may be built with (the statistics')
    # one function, under the module name numpy 2 writes and the one numpy 1.x wrote
    (_RECONSTRUCT, "numpy._core.multiarray._reconstruct"),
    (_RECONSTRUCT, "numpy.core.multiarray._reconstruct"),
]

_REFUSED_GLOBAL = re.compile(r"GLOBAL (\S+)|unrecognized function (\S+)|but got (.+)$",
                             re.MULTILINE)
"""Where torch's data-only unpickler names what it refused to call or build."""
_BOILERPLATE = ("Weights only load failed", "Please file an issue", "Check the documentation")


def read_checkpoint_file(path: Path, *, what: str) -> dict[str, Any]:
    """The dict saved in `path` (`what` names the kind of file in messages). Raises
    `CheckpointError` for a file that does not load, names code to run (refused: nothing in
    it was called), or holds something other than a dict."""
    import torch

    try:
        with torch.serialization.safe_globals(ALLOWED_GLOBALS), warnings.catch_warnings():
            # a bare pickle (not torch's zip) of a newer protocol: refused below all the same
            warnings.filterwarnings("ignore", message="Detected pickle protocol")
            state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        said = _unpickler_said(str(exc))
        refused = _REFUSED_GLOBAL.search(said)
        if refused is None:  # damaged, or no torch file: the reader stopped at what it met
            raise CheckpointError(f"{path}: not a readable {what} (torch.load's data-only "
                                  f"reader stopped: {said}); nothing in it was run") from None
        named = next(group for group in refused.groups() if group)
        raise CheckpointError(
            f"{path}: not a readable {what}: it names {named}, which is neither a tensor nor "
            f"plain data (a {what} hercs wrote names nothing else: this one is damaged, or "
            "was made to run code when opened). Nothing in it was run: hercs reads checkpoints "
            "as data only (docs/SECURITY.md)") from None
    except Exception as exc:  # not a torch file at all, cut short, unreadable
        raise CheckpointError(f"{path}: not a readable {what} ({_first_line(exc)})") from None
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: not a {what} of this version of hercs (it holds a "
                              f"{type(state).__name__}, not a dict)")
    return state


def _unpickler_said(message: str) -> str:
    """What the data-only unpickler said, without torch's advice around it (which suggests
    loading the file with `weights_only=False`: running it)."""
    kept = [part.removeprefix("WeightsUnpickler error:").strip()
            for part in message.split("\n") if not part.startswith(_BOILERPLATE)]
    return " ".join(part for part in kept if part) or "no reason given"


def _first_line(exc: Exception) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
