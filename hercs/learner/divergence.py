"""Finding where a learner's numbers stopped being finite, cheaply enough to look often.

A NaN or inf in a loss or weight is never undone, so the learner looks: after every CPU update,
once per cycle everywhere (the epoch's loss sums and one flag per parameter tensor, before
weights are published), and over its whole state before a checkpoint; an actor refuses
weights that hold one, so a run training on after it keeps nothing moving. Looking is cheap:
after a CPU update the loss row is already on the host, and the epoch's loss sums stay
non-finite once any loss in them was. `DDPGLearner` raises `hercs.errors.Diverged` with what
these name.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
import torch


def nonfinite_losses(names: Sequence[str], values: Sequence[float]) -> str | None:
    """'critic_loss = inf, q_mean = nan' for the values that are not finite; None if all are."""
    bad = [f"{name} = {value!r}" for name, value in zip(names, values, strict=True)
           if not math.isfinite(value)]
    return ", ".join(bad) or None


def nonfinite_tensors(named: Iterable[tuple[str, torch.Tensor]]) -> list[str]:
    """For each floating-point tensor that holds a NaN or an inf: its name, how many of its
    values are not finite, and which kinds. One read from the device for all the flags (on a
    GPU each read waits for the device), the details only for the tensors that fail."""
    tensors = [(name, tensor.detach()) for name, tensor in named
               if tensor.is_floating_point()]
    if not tensors:
        return []
    finite = torch.stack([torch.isfinite(t).all() for _, t in tensors]).tolist()
    found = []
    for ok, (name, tensor) in zip(finite, tensors, strict=True):
        if ok:
            continue
        bad = tensor[~torch.isfinite(tensor)]
        kinds = sorted({repr(v) for v in bad.flatten()[:1024].tolist()})
        found.append(f"{name} holds {bad.numel()} non-finite of its {tensor.numel()} values "
                     f"({', '.join(kinds)})")
    return found


def state_tensors(tree: Any, where: str) -> Iterator[tuple[str, torch.Tensor]]:
    """Every tensor of a state-dict tree (nested mappings and lists), named by its path; the
    normalisers' numpy arrays as tensors too."""
    if isinstance(tree, torch.Tensor):
        yield where, tree
    elif isinstance(tree, np.ndarray):
        yield where, torch.from_numpy(np.ascontiguousarray(tree))
    elif isinstance(tree, Mapping):
        for key, value in tree.items():
            yield from state_tensors(value, f"{where}.{key}")
    elif isinstance(tree, list | tuple):
        for index, value in enumerate(tree):
            yield from state_tensors(value, f"{where}[{index}]")
