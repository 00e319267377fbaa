"""Actor and critic of DDPG+HER, and the input preprocessing shared by actors and learner.

As the reference PyTorch HER code (`rl_modules/models.py`): actor μ(x) = max_action ·
tanh(MLP(x)), critic Q(x, a) = MLP([x, a / max_action]), x = [o_norm, g_norm], with
`hidden_layers` ReLU layers of `hidden_size` (3 × 256) and PyTorch's default `nn.Linear`
initialisation. Seeded
construction (`seed=`) runs inside `torch.random.fork_rng`: the weights depend only on the
seed and the caller's global RNG is untouched.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Protocol

import numpy as np
import torch
from torch import nn

from hercs.rl.normalizer import Normalizer
from hercs.rl.task_spec import TaskSpec


class NetworkShape(Protocol):
    """The hidden layers of both networks; `hercs.config.DDPGConfig` is one (rl stays below
    the configuration tree: it names what it reads, not where it comes from)."""

    @property
    def hidden_layers(self) -> int: ...

    @property
    def hidden_size(self) -> int: ...


def _mlp(in_dim: int, out_dim: int, config: NetworkShape) -> nn.Sequential:
    layers: list[nn.Module] = []
    width = in_dim
    for _ in range(config.hidden_layers):
        layers += [nn.Linear(width, config.hidden_size), nn.ReLU()]
        width = config.hidden_size
    layers.append(nn.Linear(width, out_dim))
    return nn.Sequential(*layers)


@contextlib.contextmanager
def _seeded(seed: int | None) -> Iterator[None]:
    """Run the block with torch's global RNG seeded by `seed`, restoring the caller's state after.

    `nn.Linear` draws its initial weights from the global generator at construction, so the
    layers must be built inside this block. `seed=None` leaves the global generator in use.
    """
    if seed is None:
        yield
        return
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        yield


class Actor(nn.Module):
    """Deterministic policy μ(o_norm, g_norm) ∈ [−max_action, max_action]^action_dim."""

    def __init__(self, *, spec: TaskSpec, config: NetworkShape, seed: int | None = None) -> None:
        super().__init__()
        self.max_action = float(spec.max_action)
        with _seeded(seed):
            self.net = _mlp(spec.obs_dim + spec.goal_dim, spec.action_dim, config)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, obs_dim + goal_dim) normalised inputs → actions (B, action_dim)."""
        return self.max_action * torch.tanh(self.net(x))


class Critic(nn.Module):
    """Action value Q(o_norm, g_norm, a); the action enters scaled by 1/max_action."""

    def __init__(self, *, spec: TaskSpec, config: NetworkShape, seed: int | None = None) -> None:
        super().__init__()
        self.max_action = float(spec.max_action)
        with _seeded(seed):
            self.net = _mlp(spec.obs_dim + spec.goal_dim + spec.action_dim, 1, config)

    def forward(self, x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """x: (B, obs_dim + goal_dim), a: (B, action_dim) → Q (B, 1)."""
        return self.net(torch.cat([x, a / self.max_action], dim=-1))

    def frozen(self, x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """`forward` with the weights as constants: gradients reach x and a, never the
        weights. The same operations as `forward`, so the same numbers; unlike switching the
        parameters' requires_grad off and on, it is safe beside a thread running `forward`."""
        h = torch.cat([x, a / self.max_action], dim=-1)
        for layer in self.net:
            if isinstance(layer, nn.Linear):
                h = nn.functional.linear(h, layer.weight.detach(), layer.bias.detach())
            else:
                h = layer(h)
        return h


class NumpyActor:
    """μ evaluated with numpy on a frozen copy of an `Actor`'s parameters, for acting.

    An actor evaluates μ one observation at a time; at batch size 1 torch's per-call overhead
    is most of the cost (bench/perf/throughput: ~70 µs per step against ~25 µs here), and every
    microsecond is taken from env stepping. Same arithmetic in float32, so the outputs agree
    with `Actor.forward` to float rounding. Rebuild it whenever the actor's weights change.
    """

    def __init__(self, actor: Actor) -> None:
        linears = [m for m in actor.net if isinstance(m, nn.Linear)]
        self.max_action = actor.max_action
        # x @ W.T + b, with W.T stored contiguous once rather than transposed per call.
        self.layers = [(m.weight.detach().cpu().numpy().T.astype(np.float32, order="C"),
                        m.bias.detach().cpu().numpy().astype(np.float32))
                       for m in linears]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """x: (B, obs_dim + goal_dim) float32 normalised inputs → actions (B, action_dim)."""
        h = np.asarray(x, dtype=np.float32)
        for w, b in self.layers[:-1]:
            h = np.maximum(h @ w + b, 0.0)
        w, b = self.layers[-1]
        return self.max_action * np.tanh(h @ w + b)


def preprocess(
    o: np.ndarray, g: np.ndarray, o_norm: Normalizer, g_norm: Normalizer, clip_obs: float
) -> np.ndarray:
    """Network input [o_norm, g_norm] (float32, last axis concatenated).

    As the reference: o and g are clipped to ±clip_obs, then normalised (which clips to
    ±clip_range). Leading shapes of o and g must agree.
    """
    o = np.clip(o, -clip_obs, clip_obs)
    g = np.clip(g, -clip_obs, clip_obs)
    return np.concatenate([o_norm.normalize(o), g_norm.normalize(g)], axis=-1)


def to_arrays(module: nn.Module) -> dict[str, np.ndarray]:
    """The module's parameters as plain float32 numpy arrays (copies), keyed by state-dict name.

    This is the wire form of network weights (`Weights.actor`).
    """
    return {name: t.detach().cpu().numpy().astype(np.float32, copy=True)
            for name, t in module.state_dict().items()}


def load_arrays(module: nn.Module, arrays: dict[str, np.ndarray]) -> None:
    """Load `to_arrays` output into `module`; names and shapes must match exactly.

    Everything is checked before anything is written, so a bad dict leaves the module as it was.
    """
    own = module.state_dict()
    missing = sorted(set(own) - set(arrays))
    unexpected = sorted(set(arrays) - set(own))
    if missing or unexpected:
        raise ValueError(f"{type(module).__name__} weights: missing {missing}, "
                         f"unexpected {unexpected}")
    tensors = {}
    for name, ref in own.items():
        arr = np.asarray(arrays[name], dtype=np.float32)
        if tuple(arr.shape) != tuple(ref.shape):
            raise ValueError(f"{type(module).__name__} weights: {name!r} has shape "
                             f"{arr.shape}, expected {tuple(ref.shape)}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{type(module).__name__} weights: {name!r} holds NaN or Inf")
        tensors[name] = torch.from_numpy(arr.copy())
    module.load_state_dict(tensors)
