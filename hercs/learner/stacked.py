"""K DDPG learners as one stacked update (issue 56's first part): the K slots' actors, critics,
targets and Adam moments held as (K, ...) tensors, each layer one `baddbmm` for all K.

A slot is the same experiment as a lone `DDPGLearner`: the same update (the critic's loss and
step, then the actor's, reference order), the same Adam (element-wise, so one Adam over a
stacked tensor is K Adams; each slot keeps its own step count, so a learner of any age can join
and bias correction stays its own), the same Polyak average. Slots share the network sizes and
the DDPG settings (a grid of seeds of one cell), not their weights, batches or normalisers.
`load_learner(k, learner)` takes a lone learner's state into slot k, and `store_learner(k,
learner)` writes slot k back, so a slot's checkpoint is a lone learner's (hercs.learner.resume)
and a stacked cell resumes alone or a lone one joins. The stack does no host synchronisation;
its caller reads the losses.

Stacking buys little in fp32 (1.05-1.18x on an AVX2 EPYC and on an AMX Xeon); the gain is bf16
autocast on stacked GEMMs where the CPU multiplies bf16 natively (1.6-1.8x at K = 4 on the Xeon,
0.15x on the EPYC, which has no bf16 GEMM; bench/perf/stacked_learner.py, docs/PERFORMANCE.md).
hercs.learner.stacked_cells runs the cells' loops around one stack.
"""

from __future__ import annotations

from collections.abc import MutableMapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from hercs.config import DDPGConfig
from hercs.learner.ddpg import LOSS_NAMES, DDPGLearner, return_bounds
from hercs.rl.task_spec import TaskSpec

ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-8
"""torch.optim.Adam's defaults, which the lone learner uses."""


class StackedMLP:
    """K MLPs of one shape as (K, in, out) weights and (K, 1, out) biases, ReLU between."""

    def __init__(self, layers: list[tuple[torch.Tensor, torch.Tensor]]) -> None:
        self.layers = layers

    @classmethod
    def zeros_like(cls, nets: Sequence[nn.Sequential]) -> StackedMLP:
        """A stack of `len(nets)` MLPs shaped as `nets[0]`, every tensor a zero leaf."""
        linears = [m for m in nets[0] if isinstance(m, nn.Linear)]
        k = len(nets)
        return cls([(torch.zeros(k, m.in_features, m.out_features, requires_grad=True),
                     torch.zeros(k, 1, m.out_features, requires_grad=True))
                    for m in linears])

    def parameters(self) -> list[torch.Tensor]:
        return [t for layer in self.layers for t in layer]

    def load(self, k: int, net: nn.Sequential) -> None:
        """Slot k's weights from `net` (nn.Linear keeps W as (out, in): stored transposed)."""
        linears = [m for m in net if isinstance(m, nn.Linear)]
        with torch.no_grad():
            for (weight, bias), m in zip(self.layers, linears, strict=True):
                weight[k].copy_(m.weight.detach().T)
                bias[k, 0].copy_(m.bias.detach())

    def store(self, k: int, net: nn.Sequential) -> None:
        linears = [m for m in net if isinstance(m, nn.Linear)]
        with torch.no_grad():
            for (weight, bias), m in zip(self.layers, linears, strict=True):
                m.weight.copy_(weight[k].T)
                m.bias.copy_(bias[k, 0])

    def __call__(self, x: torch.Tensor, *, frozen: bool = False) -> torch.Tensor:
        """x: (K, B, in) → (K, B, out); `frozen`: the weights as constants (no gradient
        reaches them, as `Critic.frozen`)."""
        h = x
        last = len(self.layers) - 1
        for i, (weight, bias) in enumerate(self.layers):
            if frozen:
                weight, bias = weight.detach(), bias.detach()
            h = torch.baddbmm(bias, h, weight)
            if i < last:
                h = torch.relu(h)
        return h


class StackedAdam:
    """torch.optim.Adam's update (no weight decay, no amsgrad) over stacked tensors, with one
    step count per slot: slot k's bias correction is its own, as its lone learner's was."""

    def __init__(self, params: list[torch.Tensor], *, lr: float, slots: int) -> None:
        self.params, self.lr = params, lr
        self.exp_avg = [torch.zeros_like(p) for p in params]
        self.exp_avg_sq = [torch.zeros_like(p) for p in params]
        self.steps = torch.zeros(slots, dtype=torch.float64)

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        beta1, beta2 = ADAM_BETAS
        self.steps += 1
        correction1 = 1.0 - beta1 ** self.steps
        correction2 = 1.0 - beta2 ** self.steps
        for p, m, v in zip(self.params, self.exp_avg, self.exp_avg_sq, strict=True):
            shape = (-1,) + (1,) * (p.dim() - 1)
            step_size = (self.lr / correction1).to(p.dtype).view(shape)
            root2 = correction2.sqrt().to(p.dtype).view(shape)
            grad = p.grad
            assert grad is not None, "a stacked parameter took no part in the loss"
            m.lerp_(grad, 1.0 - beta1)
            v.mul_(beta2).addcmul_(grad, grad, value=1.0 - beta2)
            p.sub_(step_size * m / (v.sqrt() / root2 + ADAM_EPS))

    def load(self, k: int, state: MutableMapping[torch.Tensor, Any],
             params: Sequence[torch.Tensor]) -> None:
        """Slot k's moments and step from a lone torch Adam's `state` (keyed by its params)."""
        steps = set()
        for m, v, p in zip(self.exp_avg, self.exp_avg_sq, params, strict=True):
            entry = state.get(p)
            if entry:
                m[k].copy_(_stacked_form(entry["exp_avg"], m[k].shape))
                v[k].copy_(_stacked_form(entry["exp_avg_sq"], v[k].shape))
                steps.add(float(entry["step"]))
            else:  # a learner that never stepped
                m[k].zero_()
                v[k].zero_()
                steps.add(0.0)
        if len(steps) != 1:
            raise ValueError(f"slot {k}: the lone optimiser's parameters have step counts "
                             f"{sorted(steps)}; one learner steps all of them together")
        self.steps[k] = steps.pop()

    def store(self, k: int, state: MutableMapping[torch.Tensor, Any],
              params: Sequence[torch.Tensor]) -> None:
        for m, v, p in zip(self.exp_avg, self.exp_avg_sq, params, strict=True):
            entry = state.setdefault(p, {})
            entry["exp_avg"] = _lone_form(m[k], p.shape)
            entry["exp_avg_sq"] = _lone_form(v[k], p.shape)
            entry["step"] = torch.tensor(float(self.steps[k]))


def _stacked_form(lone: torch.Tensor, shape: torch.Size) -> torch.Tensor:
    """A lone layer's tensor as a slot holds it: a weight (out, in) as (in, out), a bias (out,)
    as (1, out)."""
    return lone.reshape(shape) if lone.dim() == 1 else lone.T


def _lone_form(slot: torch.Tensor, shape: torch.Size) -> torch.Tensor:
    return (slot.reshape(shape) if len(shape) == 1 else slot.T).clone().contiguous()


def _as_stack_order(net: nn.Sequential) -> list[torch.Tensor]:
    """A lone MLP's parameters in the stack's order (weight, bias per layer)."""
    return [t for m in net if isinstance(m, nn.Linear) for t in (m.weight, m.bias)]


class StackedDDPG:
    """K slots of DDPG; `train(inputs)` is one update of every slot on its own minibatch."""

    def __init__(self, *, spec: TaskSpec, config: DDPGConfig, learners: Sequence[DDPGLearner],
                 precision: str = "fp32") -> None:
        if not learners:
            raise ValueError("StackedDDPG: no learners to stack")
        if precision not in ("fp32", "bf16"):
            raise ValueError(f"StackedDDPG: precision {precision!r}; stacked slots run fp32 "
                             "or bf16 autocast")
        self.spec, self.config, self.precision = spec, config, precision
        self.slots = len(learners)
        actors = [lr.actor.net for lr in learners]
        critics = [lr.critic.net for lr in learners]
        self.actor, self.actor_target = (StackedMLP.zeros_like(actors) for _ in range(2))
        self.critic, self.critic_target = (StackedMLP.zeros_like(critics) for _ in range(2))
        for target in (self.actor_target, self.critic_target):
            for tensor in target.parameters():
                tensor.requires_grad_(False)
        self.actor_optim = StackedAdam(self.actor.parameters(), lr=config.lr_actor,
                                       slots=self.slots)
        self.critic_optim = StackedAdam(self.critic.parameters(), lr=config.lr_critic,
                                        slots=self.slots)
        for k, learner in enumerate(learners):
            self.load_learner(k, learner)
        self.clip = return_bounds(spec, config.gamma) if config.clip_return else None

    # -- a slot in, a slot out -----------------------------------------------------------
    def _counterparts(self, learner: DDPGLearner) -> tuple[
            list[tuple[StackedMLP, nn.Sequential]],
            list[tuple[StackedAdam, MutableMapping[torch.Tensor, Any], list[torch.Tensor]]]]:
        """Each stacked network beside `learner`'s, and each stacked Adam beside its state and
        parameters (in the stack's order)."""
        nets = [(self.actor, learner.actor.net), (self.actor_target, learner.actor_target.net),
                (self.critic, learner.critic.net),
                (self.critic_target, learner.critic_target.net)]
        optims: list[tuple[StackedAdam, MutableMapping[torch.Tensor, Any],
                           list[torch.Tensor]]] = [
            (self.actor_optim, learner.actor_optim.state, _as_stack_order(learner.actor.net)),
            (self.critic_optim, learner.critic_optim.state,
             _as_stack_order(learner.critic.net))]
        return nets, optims

    def load_learner(self, k: int, learner: DDPGLearner) -> None:
        """Slot k becomes `learner`: networks, targets and Adam moments and step."""
        nets, optims = self._counterparts(learner)
        for stacked, net in nets:
            stacked.load(k, net)
        for optim, state, params in optims:
            optim.load(k, state, params)

    def store_learner(self, k: int, learner: DDPGLearner) -> None:
        """Slot k written into `learner`, so that its `state_dict()` is slot k's checkpoint."""
        nets, optims = self._counterparts(learner)
        for stacked, net in nets:
            stacked.store(k, net)
        for optim, state, params in optims:
            optim.store(k, state, params)

    def store_actor(self, k: int, learner: DDPGLearner) -> None:
        """Slot k's actor μ alone written into `learner` (what a weights broadcast reads),
        cheaper than `store_learner` once a cycle."""
        self.actor.store(k, learner.actor.net)

    @torch.no_grad()
    def nonfinite_slots(self) -> list[int]:
        """The slots with a non-finite parameter in μ or Q (one reduction per tensor)."""
        bad = torch.zeros(self.slots, dtype=torch.bool)
        for tensor in (*self.actor.parameters(), *self.critic.parameters()):
            bad |= ~torch.isfinite(tensor).flatten(1).all(dim=1)
        return [k for k in range(self.slots) if bool(bad[k])]

    # -- the update ------------------------------------------------------------------------
    def _autocast(self) -> torch.autocast:
        return torch.autocast("cpu", dtype=torch.bfloat16, enabled=self.precision == "bf16",
                              cache_enabled=False)

    def _q(self, net: StackedMLP, x: torch.Tensor, a: torch.Tensor, *,
           frozen: bool = False) -> torch.Tensor:
        return net(torch.cat([x, a / self.spec.max_action], dim=-1), frozen=frozen)

    def _pi(self, net: StackedMLP, x: torch.Tensor) -> torch.Tensor:
        return self.spec.max_action * torch.tanh(net(x))

    def train(self, s: torch.Tensor, s2: torch.Tensor, u: torch.Tensor,
              r: torch.Tensor) -> torch.Tensor:
        """One update of every slot: s, s2 (K, B, obs+goal) normalised inputs, u (K, B, act),
        r (K, B, 1), each slot's `DDPGLearner.host_inputs` stacked. Returns the (K, 5) losses
        in `LOSS_NAMES` order (critic loss, actor loss, mean Q, mean y, action L2)."""
        cfg = self.config
        with torch.no_grad():
            y = r + cfg.gamma * self._q(self.critic_target, s2, self._pi(self.actor_target, s2))
            if self.clip is not None:
                y = torch.clamp(y, *self.clip)
        with self._autocast():
            q = self._q(self.critic, s, u).float()
        critic_loss = (y - q).pow(2).mean(dim=(1, 2))
        self.critic_optim.zero_grad()
        critic_loss.sum().backward()  # slots' parameters are disjoint: slot k's gradient is ∇L_k
        with self._autocast():
            pi = self._pi(self.actor, s).float()
        action_l2 = (pi / self.spec.max_action).pow(2).mean(dim=(1, 2))
        with self._autocast():
            actor_q = self._q(self.critic, s, pi, frozen=True).float()
        actor_loss = -actor_q.mean(dim=(1, 2)) + cfg.action_l2 * action_l2
        self.actor_optim.zero_grad()
        actor_loss.sum().backward()
        self.actor_optim.step()
        self.critic_optim.step()
        return torch.stack([critic_loss.detach(), actor_loss.detach(),
                            q.detach().mean(dim=(1, 2)), y.mean(dim=(1, 2)), action_l2.detach()],
                           dim=1)

    @torch.no_grad()
    def update_targets(self) -> None:
        """Polyak θ' ← polyak·θ' + (1−polyak)·θ, every slot (once per cycle, as the lone one)."""
        rho = self.config.polyak
        for net, target in ((self.actor, self.actor_target), (self.critic, self.critic_target)):
            for p, p_targ in zip(net.parameters(), target.parameters(), strict=True):
                p_targ.copy_((1.0 - rho) * p + rho * p_targ)


def stacked_inputs(learners: Sequence[DDPGLearner],
                   batches: Sequence[object]) -> tuple[torch.Tensor, ...]:
    """Each slot's minibatch preprocessed with its own learner's normalisers (as its lone
    update would), stacked into (s, s2, u, r) of shape (K, B, ...)."""
    parts = [learner.host_inputs(batch)  # type: ignore[arg-type]
             for learner, batch in zip(learners, batches, strict=True)]
    return tuple(torch.from_numpy(np.stack(column)) for column in zip(*parts, strict=True))


__all__ = ["LOSS_NAMES", "StackedAdam", "StackedDDPG", "StackedMLP", "stacked_inputs"]
