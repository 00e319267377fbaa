"""DDPG update of DDPG+HER, as the reference PyTorch HER code (`rl_modules/ddpg_agent.py`).

`DDPGLearner.train(batch)` is one reference `_update_network` call;
`update_targets()` is the once-per-cycle Polyak average (docs/DESIGN.md §4.6). Networks are
built on the CPU and checkpoints hold host tensors, so neither depends on the device. The
normalisers are the replay's; the learner adopts their statistics. A served batch is checked
once, on arrival (`decode_minibatch` returns a `CheckedBatch` that `train` takes as it is);
a batch handed to `train` directly is checked there. Torch's thread count is the service's to
set, never this module's (docs/DESIGN.md §10).
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import torch

from hercs.config import PRECISIONS, DDPGConfig
from hercs.errors import ConfigError, Diverged
from hercs.learner.cuda_graph import CapturedUpdate, CaptureFailed, loss_row
from hercs.learner.divergence import nonfinite_losses, nonfinite_tensors, state_tensors
from hercs.learner.tf32 import TF32Products
from hercs.rl.networks import Actor, Critic, preprocess, to_arrays
from hercs.rl.normalizer import Normalizer, NormalizerState
from hercs.rl.policy import PolicyWeights
from hercs.rl.seeding import int_seed
from hercs.rl.task_registry import TaskSpec
from hercs.wire.batch import CheckedBatch, TransitionBatch, transition_shapes

log = logging.getLogger(__name__)

LOSS_NAMES = ("critic_loss", "actor_loss", "q_mean", "y_mean", "action_l2")
"""What one update reports, in the order of `DDPGLearner.step_tensors`' tensors."""
LossTensors = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]


def critic_target(
    r: torch.Tensor,
    s2: torch.Tensor,
    *,
    actor_target: Actor,
    critic_target: Critic,
    gamma: float,
    clip_return: tuple[float, float] | None,
) -> torch.Tensor:
    """y = r + γ · Q'(s', μ'(s')), clipped to the bounds `clip_return` = (low, high) unless
    it is None.

    r: (B, 1); s2: (B, obs_dim + goal_dim) normalised next inputs. No gradient flows through
    y. There is no terminal mask: episodes end by time limit only, as in the reference.
    With sparse rewards in [r_min, r_max], r_min/(1−γ) and r_max/(1−γ) bound every true
    return (`return_bounds`; Fetch: −1/(1−γ) and 0).
    """
    with torch.no_grad():
        y = r + gamma * critic_target(s2, actor_target(s2))
        if clip_return is not None:
            y = torch.clamp(y, *clip_return)
    return y


def return_bounds(spec: TaskSpec, gamma: float) -> tuple[float, float]:
    """The range of a discounted return when every reward is the task's success or failure
    reward: the reference's [−1/(1−γ), 0] for Fetch's −1/0, [0, 1/(1−γ)] for PointMaze's 0/1."""
    low, high = sorted((spec.failure_reward, spec.success_reward))
    return low / (1.0 - gamma), high / (1.0 - gamma)


def resolve_device(name: str) -> torch.device:
    """`learner.device` as a torch device: auto = the first CUDA GPU if torch sees one, else
    the CPU. Asking for CUDA where there is none is a ConfigError that says so."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(
                f"learner.device={name}: torch sees no CUDA device (torch "
                f"{torch.__version__}, CUDA build {torch.version.cuda or 'none'}); use "
                "learner.device=auto or cpu, or install a CUDA build of torch (docs/GUIDE.md, "
                "'GPU and many actors')")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise ConfigError(f"learner.device={name}: only {torch.cuda.device_count()} "
                              "CUDA device(s) visible")
    return device


def _to_host(value: Any) -> Any:
    """A state-dict tree with every tensor copied to the CPU (checkpoints load anywhere)."""
    if isinstance(value, torch.Tensor):
        return value.detach().to("cpu", copy=True)
    if isinstance(value, Mapping):
        return {key: _to_host(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_to_host(item) for item in value)
    return copy.deepcopy(value)


class DDPGLearner:
    """Actor, critic, their targets and optimisers; one `train` step per minibatch."""

    def __init__(self, *, spec: TaskSpec, config: DDPGConfig, seed: int,
                 device: str | torch.device = "cpu", precision: str = "fp32",
                 parallel_halves: bool = False, cuda_graph: bool = False) -> None:
        if precision not in PRECISIONS:
            raise ConfigError(f"learner.precision: got {precision!r}, must be one of "
                              f"{', '.join(PRECISIONS)}")
        self.spec = spec
        self.config = config
        self.precision = precision
        self.device = device if isinstance(device, torch.device) else resolve_device(device)
        self.actor = Actor(spec=spec, config=config, seed=int_seed(seed, "learner", "actor"))
        self.critic = Critic(spec=spec, config=config, seed=int_seed(seed, "learner", "critic"))
        self.actor.to(self.device)
        self.critic.to(self.device)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        # fused: one kernel per step instead of a loop over the parameters (measured +9 % of
        # updates per CPU-second on this machine's CPU); the same Adam, up to float rounding
        # capturable on a GPU: Adam's step count stays on the device, as a CUDA graph needs
        on_gpu = self.device.type == "cuda"
        self.actor_optim = torch.optim.Adam(self.actor.parameters(), lr=config.lr_actor,
                                            fused=True, capturable=on_gpu)
        self.critic_optim = torch.optim.Adam(self.critic.parameters(), lr=config.lr_critic,
                                             fused=True, capturable=on_gpu)
        # the critic's half of each update on a second thread (CPU only: on a GPU both halves
        # queue on one stream, and a second host thread would only add synchronisation)
        self._branches = (ThreadPoolExecutor(1, thread_name_prefix="critic-half")
                          if parallel_halves and self.device.type == "cpu" else None)
        self.o_norm = Normalizer(spec.obs_dim, eps=config.norm_eps, clip_range=config.norm_clip)
        self.g_norm = Normalizer(spec.goal_dim, eps=config.norm_eps, clip_range=config.norm_clip)
        self.loss_sums = torch.zeros(len(LOSS_NAMES), dtype=torch.float64, device=self.device)
        self._loss_count = 0
        self._captured = CapturedUpdate(self) if cuda_graph and on_gpu else None
        self.updates = 0
        """Minibatch updates done (Adam steps per network)."""
        self.target_updates = 0
        """Polyak updates done (one per cycle)."""

    def set_normalizer_state(
        self, o_state: Mapping[str, np.ndarray | float], g_state: Mapping[str, np.ndarray | float]
    ) -> None:
        """Adopt the replay's normaliser statistics (`Normalizer.state_dict()` form)."""
        o_norm, g_norm = self.o_norm.with_state(o_state), self.g_norm.with_state(g_state)
        self.o_norm, self.g_norm = o_norm, g_norm

    def train(self, batch: TransitionBatch) -> None:
        """One DDPG step whose losses are added to running sums on the learner's device
        (`loss_means` reads them): no host synchronisation per update. On a GPU with
        `cuda_graph`, the whole step is one captured CUDA graph replayed per minibatch. On a
        CPU a loss that is not finite raises `Diverged` naming this update."""
        captured = self._captured
        if captured is not None:
            try:
                captured.train(self.host_inputs(batch))
            except CaptureFailed as failure:
                log.warning("learner.cuda_graph: the update could not be captured (%s); "
                            "training with the eager update", failure)
                self._captured = captured = None
        if captured is None:
            row = loss_row(self.precise(self._eager_step, batch))
            # On a CPU this costs microseconds and names the very update; on a GPU it would
            # make the host wait for the device each update, so there `check_finite` finds a
            # bad loss in the sums once per cycle.
            if self.device.type == "cpu" and not bool(torch.isfinite(row).all()):
                raise Diverged(f"update {self.updates + 1}: "
                               f"{nonfinite_losses(LOSS_NAMES, row.tolist())}")
            self.loss_sums += row
        self._loss_count += 1
        self.updates += 1

    def count_update(self, losses: torch.Tensor) -> None:
        """An update done for this learner elsewhere (a stack's slot, hercs.learner.stacked):
        its `LOSS_NAMES` row added to the sums `loss_means` reads, and the update counted."""
        self.loss_sums += losses.to(self.loss_sums)
        self._loss_count += 1
        self.updates += 1

    def check_finite(self, *, first_update: int) -> None:
        """Raise `Diverged` if a loss of the updates since the last epoch end, or a parameter of
        μ or Q, is not finite, naming which; the caller says which update its last check
        passed after (`first_update` is the one after it). Once per cycle, before the weights
        are published: one read of the loss sums, one of a flag per parameter tensor."""
        losses = nonfinite_losses(LOSS_NAMES, self.loss_sums.tolist())
        if losses is not None:  # a sum stays non-finite once one of its losses was
            raise Diverged(f"updates {first_update}-{self.updates}: {losses} (the losses' sums "
                           "since the epoch began)")
        params = nonfinite_tensors([*state_tensors(dict(self.actor.named_parameters()), "actor"),
                                    *state_tensors(dict(self.critic.named_parameters()),
                                                   "critic")])
        if params:
            raise Diverged(f"after update {self.updates}: {'; '.join(params)}")

    def loss_means(self) -> dict[str, float]:
        """The mean of each loss over the `train` steps since the last call (NaN if none),
        and the sums reset."""
        sums = self.loss_sums.tolist()
        count, self._loss_count = self._loss_count, 0
        self.loss_sums.zero_()  # in place: a captured graph adds to this very tensor
        return {name: total / count if count else float("nan")
                for name, total in zip(LOSS_NAMES, sums, strict=True)}

    def precise(self, fn: Any, *args: Any) -> Any:
        """`fn(*args)` in the learner's precision (TF32 products for tf32; bf16 autocast is
        entered by each half around its online passes)."""
        if self.precision != "tf32":
            return fn(*args)
        with TF32Products():  # every product of the step, the target and backward included
            return fn(*args)

    def host_inputs(self, batch: TransitionBatch) -> tuple[np.ndarray, ...]:
        """(s, s', u, r) as float32 host arrays: s = [o, g], s' = [o', g] clipped to
        ±clip_obs and normalised with the replay's stats; r as (B, 1), so that y broadcasts
        row-wise, not to (B, B)."""
        o, g, u, r, o2 = self._check_batch(batch)
        clip = self.config.clip_obs
        return (preprocess(o, g, self.o_norm, self.g_norm, clip),
                preprocess(o2, g, self.o_norm, self.g_norm, clip),
                np.array(u),  # a copy: wire arrays are read-only views
                np.array(r.reshape(-1, 1)))

    def _eager_step(self, batch: TransitionBatch) -> LossTensors:
        return self.step_tensors(*(self._on_device(a) for a in self.host_inputs(batch)))

    def step_tensors(self, s: torch.Tensor, s2: torch.Tensor, u_t: torch.Tensor,
                     r_t: torch.Tensor) -> LossTensors:
        """The update on device tensors, both Adam steps included; the loss tensors in
        `LOSS_NAMES` order. The update counter is the caller's (a graph capture runs this)."""
        # The two halves read the same parameters and write disjoint gradients, so they may
        # run at once; the critic's Adam step waits for both, since the actor's backward pass
        # reads the critic's weights.
        if self._branches is None:
            critic_loss, q, y = self._critic_half(s, s2, u_t, r_t)
            actor_loss, action_l2 = self._actor_half(s)
        else:
            # precise again on that thread: torch's dispatch modes (TF32) are per thread
            critic_half = self._branches.submit(self.precise, self._critic_half, s, s2, u_t,
                                                r_t)
            try:
                actor_loss, action_l2 = self._actor_half(s)
            finally:  # never leave the critic's half running into the next update
                critic_loss, q, y = critic_half.result()
        self.critic_optim.step()
        return critic_loss, actor_loss, q.mean(), y.mean(), action_l2

    def _critic_half(self, s: torch.Tensor, s2: torch.Tensor, u_t: torch.Tensor,
                     r_t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The critic's loss and gradients (its Adam step is the caller's)."""
        cfg = self.config
        # Critic target: y = clip(r + γ Q'(s', μ'(s')), −1/(1−γ), 0).
        y = critic_target(
            r_t, s2,
            actor_target=self.actor_target, critic_target=self.critic_target,
            gamma=cfg.gamma,
            clip_return=return_bounds(self.spec, cfg.gamma) if cfg.clip_return else None,
        )
        # Critic loss: L_Q = mean (y − Q(s, u))².
        with self._autocast():
            q = self.critic(s, u_t).float()
        critic_loss = (y - q).pow(2).mean()
        self.critic_optim.zero_grad(set_to_none=True)
        critic_loss.backward()
        return critic_loss, q, y

    def _actor_half(self, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The actor's loss, gradients and Adam step.

        L_μ = −mean Q(s, μ(s)) + action_l2 · mean (μ(s)/max_action)², with the critic's
        weights as constants (`Critic.frozen`): L_μ's gradient with respect to them is not
        computed at all."""
        with self._autocast():
            pi = self.actor(s)
        pi = pi.float()
        action_l2 = (pi / self.spec.max_action).pow(2).mean()
        with self._autocast():
            actor_q = self.critic.frozen(s, pi).float()
        actor_loss = -actor_q.mean() + self.config.action_l2 * action_l2
        self.actor_optim.zero_grad(set_to_none=True)
        actor_loss.backward()
        self.actor_optim.step()
        return actor_loss, action_l2

    def _autocast(self) -> torch.autocast:
        """bf16 autocast of the online networks' passes, or a disabled one (fp32)."""
        # no cast cache: each region runs one pass, so it saved nothing, and a CUDA graph
        # capture needs it off
        return torch.autocast(self.device.type, dtype=torch.bfloat16,
                              enabled=self.precision == "bf16", cache_enabled=False)

    def update_targets(self) -> None:
        """Polyak averaging θ' ← polyak·θ' + (1−polyak)·θ for μ' and Q' (once per cycle)."""
        rho = self.config.polyak
        with torch.no_grad():
            for net, target in ((self.actor, self.actor_target),
                                (self.critic, self.critic_target)):
                for p, p_targ in zip(net.parameters(), target.parameters(), strict=True):
                    p_targ.copy_((1.0 - rho) * p + rho * p_targ)
        self.target_updates += 1

    def actor_weights(self) -> dict[str, np.ndarray]:
        """μ's parameters as float32 numpy arrays, for the `Weights` broadcast."""
        return to_arrays(self.actor)

    def normalizer_state(self) -> tuple[NormalizerState, NormalizerState]:
        """(o_state, g_state) the learner currently uses, to broadcast with the weights."""
        return self.o_norm.state_dict(), self.g_norm.state_dict()

    def policy_weights(self, version: int) -> PolicyWeights:
        """Everything an actor needs, tagged with `version`."""
        o_state, g_state = self.normalizer_state()
        return PolicyWeights(version=version, actor=self.actor_weights(),
                             o_stats=o_state, g_stats=g_state)

    def state_dict(self) -> dict[str, Any]:
        """Checkpoint: nets, targets, optimisers, normaliser stats, counters (copies, every
        tensor on the CPU)."""
        return _to_host({
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "actor_target": self.actor_target.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "actor_optim": self.actor_optim.state_dict(),
            "critic_optim": self.critic_optim.state_dict(),
            "o_norm": self.o_norm.state_dict(),
            "g_norm": self.g_norm.state_dict(),
            "updates": self.updates,
            "target_updates": self.target_updates,
        })

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore a `state_dict()` checkpoint of a learner with the same spec and config."""
        expected = {"actor", "critic", "actor_target", "critic_target", "actor_optim",
                    "critic_optim", "o_norm", "g_norm", "updates", "target_updates"}
        missing = sorted(expected - set(state))
        if missing:
            raise ValueError(f"DDPGLearner.load_state_dict: missing key(s) {missing}; "
                             "is this a learner checkpoint?")
        self.set_normalizer_state(state["o_norm"], state["g_norm"])
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        self.actor_target.load_state_dict(state["actor_target"])
        self.critic_target.load_state_dict(state["critic_target"])
        self.actor_optim.load_state_dict(state["actor_optim"])
        self.critic_optim.load_state_dict(state["critic_optim"])
        self.updates = int(state["updates"])
        self.target_updates = int(state["target_updates"])
        if self._captured is not None:  # the optimisers' state tensors are new objects now
            self._captured = CapturedUpdate(self)

    def _on_device(self, array: np.ndarray) -> torch.Tensor:
        """A host array as a tensor on the learner's device: shared memory on the CPU; on a
        GPU one pinned copy, sent without blocking the host."""
        tensor = torch.from_numpy(array)
        if self.device.type == "cpu":
            return tensor
        return tensor.pin_memory().to(self.device, non_blocking=True)

    def _check_batch(self, batch: TransitionBatch) -> TransitionBatch:
        """The same minibatch with float32 arrays of checked shapes (r as (B,): a (B,) r plus
        a (B, 1) Q' would silently broadcast to (B, B), so `train` reshapes it); a
        `CheckedBatch` (decoded from the wire, checked there) as it is."""
        if isinstance(batch, CheckedBatch):
            return batch
        o, g, u, r, o2 = (np.asarray(value, dtype=np.float32) for value in batch)
        b = o.shape[0] if o.ndim == 2 else -1
        want = transition_shapes(self.spec, b)
        for key, arr in zip(("o", "g", "u", "o2"), (o, g, u, o2), strict=True):
            if b < 1 or arr.shape != want[key]:
                raise ValueError(f"DDPGLearner.train: {key!r} has shape {arr.shape}, "
                                 f"expected {want[key]} (B from 'o')")
        if r.size != b or r.ndim > 2:
            raise ValueError(f"DDPGLearner.train: 'r' has shape {r.shape}, expected ({b},) "
                             f"or ({b}, 1)")
        return TransitionBatch(o=o, g=g, u=u, r=np.ascontiguousarray(r.reshape(b)), o2=o2)
