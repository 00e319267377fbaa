"""The whole DDPG update as one captured CUDA graph (`learner.cuda_graph`, on a GPU).

One graph launch per minibatch instead of ~170 kernel launches with Python between them (at the
paper's minibatch an eager update leaves the GPU waiting on the host); the host only normalises
the minibatch and copies it into the graph's fixed inputs. The graph reads parameters, targets
and optimiser state by address, so in-place changes are seen; `DDPGLearner.load_state_dict`
recaptures, since it replaces the optimisers' state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
import torch
from torch import nn


class CapturableLearner(Protocol):
    """What the capture reads of `hercs.learner.ddpg.DDPGLearner` (named here, so that this
    module does not import the learner that uses it)."""

    @property
    def device(self) -> torch.device: ...

    @property
    def actor(self) -> nn.Module: ...

    @property
    def critic(self) -> nn.Module: ...

    @property
    def actor_optim(self) -> torch.optim.Optimizer: ...

    @property
    def critic_optim(self) -> torch.optim.Optimizer: ...

    @property
    def loss_sums(self) -> torch.Tensor: ...

    def precise(self, fn: Callable[..., Any], *args: Any) -> Any: ...

    def step_tensors(self, s: torch.Tensor, s2: torch.Tensor, u_t: torch.Tensor,
                     r_t: torch.Tensor) -> tuple[torch.Tensor, ...]: ...


def loss_row(stats: tuple[torch.Tensor, ...]) -> torch.Tensor:
    """An update's losses as one float64 row to add to the sums, cut from autograd: the losses
    require grad, and an in-place sum of them would chain every update's graph onto the sums
    tensor for as long as the process runs (+248 MiB per 3,000 updates before this)."""
    return torch.stack(stats).detach().double()


WARMUP_STEPS = 3
"""Eager steps on a side stream before the capture (cuBLAS and the allocator settle); their
effect on the parameters and the optimisers is undone before the first real step."""


class CaptureFailed(RuntimeError):
    """The update could not be captured; the learner's state is as it was before the try."""


class CapturedUpdate:
    """The learner's `step_tensors` captured at the first minibatch, replayed for each."""

    def __init__(self, learner: CapturableLearner) -> None:
        self.learner = learner
        self.graph: torch.cuda.CUDAGraph | None = None
        self.inputs: list[torch.Tensor] = []
        self.staging: list[torch.Tensor] = []
        self.copied: torch.cuda.Event | None = None

    def train(self, host: tuple[np.ndarray, ...]) -> None:
        """One update on the host arrays (s, s', u, r), its losses added to the sums."""
        if self.graph is None:
            self._capture(host)
        else:
            self._copy_in(host)
        assert self.graph is not None
        self.graph.replay()

    def _copy_in(self, host: tuple[np.ndarray, ...]) -> None:
        """Host arrays → pinned staging → the graph's inputs, without blocking the host on the
        GPU except where the staging buffers are still being read by the last copy."""
        if self.copied is not None:
            self.copied.synchronize()
        for array, staging, target in zip(host, self.staging, self.inputs, strict=True):
            if array.shape != tuple(target.shape):
                raise ValueError(f"CapturedUpdate: an input of shape {array.shape}, the graph "
                                 f"was captured for {tuple(target.shape)}")
            staging.numpy()[...] = array
            target.copy_(staging, non_blocking=True)
        self.copied = torch.cuda.Event()
        self.copied.record()

    def _capture(self, host: tuple[np.ndarray, ...]) -> None:
        learner = self.learner
        device = learner.device
        self.inputs = [torch.empty(a.shape, dtype=torch.float32, device=device) for a in host]
        self.staging = [torch.empty(a.shape, dtype=torch.float32, pin_memory=True)
                        for a in host]
        self._copy_in(host)
        saved = _training_state(learner)
        try:
            side = torch.cuda.Stream(device)
            side.wait_stream(torch.cuda.current_stream(device))
            with torch.cuda.stream(side):
                for _ in range(WARMUP_STEPS):
                    learner.precise(learner.step_tensors, *self.inputs)
            torch.cuda.current_stream(device).wait_stream(side)
            _restore_training_state(learner, saved)
            graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(graph):
                stats = learner.precise(learner.step_tensors, *self.inputs)
                learner.loss_sums.add_(loss_row(stats))
        except Exception as exc:  # this torch, GPU or driver cannot capture the update
            torch.cuda.synchronize(device)
            _restore_training_state(learner, saved)
            raise CaptureFailed(f"{type(exc).__name__}: {exc}") from exc
        self.graph = graph


_Saved = tuple[list[torch.Tensor], dict[int, dict[str, torch.Tensor]]]


def _training_state(learner: CapturableLearner) -> _Saved:
    """Copies of the online networks' parameters and the optimisers' state."""
    params = [p.detach().clone() for net in (learner.actor, learner.critic)
              for p in net.parameters()]
    state = {id(p): {k: v.clone() for k, v in s.items() if isinstance(v, torch.Tensor)}
             for optim in (learner.actor_optim, learner.critic_optim)
             for p, s in optim.state.items()}
    return params, state


def _restore_training_state(learner: CapturableLearner, saved: _Saved) -> None:
    """Undo the warm-up in place (the graph will hold these tensors' addresses): parameters
    back, and each optimiser state back, or zeroed where the warm-up created it (a fresh
    Adam's first step starts from zero moments and count)."""
    params, state = saved
    with torch.no_grad():
        nets = [p for net in (learner.actor, learner.critic) for p in net.parameters()]
        for param, copy in zip(nets, params, strict=True):
            param.copy_(copy)
        for optim in (learner.actor_optim, learner.critic_optim):
            for p, s in optim.state.items():
                before = state.get(id(p), {})
                for key, value in s.items():
                    if isinstance(value, torch.Tensor):
                        if key in before:
                            value.copy_(before[key])
                        else:
                            value.zero_()
