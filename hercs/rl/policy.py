"""What an actor holds: the actor network, the o/g normalisers and the weights version.

Exploration is the reference's `_select_actions`: a = clip(μ(o, g) + noise_eps · max_action ·
N(0, I)), then with probability random_eps the whole action is replaced by a uniform one.
`explore=False` returns μ(o, g): the evaluator's deterministic test policy.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hercs.rl.networks import Actor, NetworkShape, NumpyActor, load_arrays, preprocess, to_arrays
from hercs.rl.normalizer import Normalizer, NormalizerState
from hercs.rl.task_spec import TaskSpec


class PolicySettings(NetworkShape, Protocol):
    """What a policy reads of DDPG's settings; `hercs.config.DDPGConfig` is one."""

    @property
    def norm_eps(self) -> float: ...

    @property
    def norm_clip(self) -> float: ...

    @property
    def clip_obs(self) -> float: ...

    @property
    def noise_eps(self) -> float: ...

    @property
    def random_eps(self) -> float: ...

INITIAL_VERSION = -1
"""Version of a policy that has not received any Weights yet (its own seeded init)."""


@dataclass
class PolicyWeights:
    """Everything an actor needs to act: the wire content of a `Weights` message."""

    version: int
    actor: dict[str, np.ndarray]
    """Actor parameters by state-dict name, float32."""
    o_stats: NormalizerState
    """Observation normaliser `state_dict()` (sum, sumsq, count, mean, std)."""
    g_stats: NormalizerState
    """Goal normaliser `state_dict()`."""


class Policy:
    """The acting half of DDPG: μ with its normalisers; no critic, no optimiser."""

    def __init__(self, *, spec: TaskSpec, config: PolicySettings, seed: int | None = None) -> None:
        self.spec = spec
        self.config = config
        self.actor = Actor(spec=spec, config=config, seed=seed)
        self.actor.eval()
        self._mu = NumpyActor(self.actor)
        self.o_norm = Normalizer(spec.obs_dim, eps=config.norm_eps, clip_range=config.norm_clip)
        self.g_norm = Normalizer(spec.goal_dim, eps=config.norm_eps, clip_range=config.norm_clip)
        self.version = INITIAL_VERSION

    def act(
        self,
        o: np.ndarray,
        g: np.ndarray,
        *,
        explore: bool,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """Action(s) for observation(s) o and goal(s) g, float32.

        o: (obs_dim,) or (n, obs_dim) for n envs; g: (goal_dim,) or (n, goal_dim). Returns
        (action_dim,) or (n, action_dim). With `explore`, each row gets its own noise and its
        own random-action coin, drawn from `rng` (always the same number of draws per call).
        """
        single = np.ndim(o) == 1
        o2 = np.atleast_2d(np.asarray(o, dtype=np.float64))
        g2 = np.atleast_2d(np.asarray(g, dtype=np.float64))
        x = preprocess(o2, g2, self.o_norm, self.g_norm, self.config.clip_obs)
        a = self._mu(x).astype(np.float64)
        if explore:
            if rng is None:
                raise ValueError("Policy.act: explore=True needs an rng (np.random.Generator)")
            a = explore_actions(a, rng=rng, max_action=self.spec.max_action,
                                noise_eps=self.config.noise_eps,
                                random_eps=self.config.random_eps)
        a = a.astype(np.float32)
        return a[0] if single else a

    def load_weights(
        self,
        actor_params: Mapping[str, np.ndarray],
        o_stats: Mapping[str, np.ndarray | float],
        g_stats: Mapping[str, np.ndarray | float],
        version: int,
    ) -> None:
        """Adopt broadcast weights. All parts are validated first; on error nothing changes."""
        o_norm, g_norm = self.o_norm.with_state(o_stats), self.g_norm.with_state(g_stats)
        load_arrays(self.actor, dict(actor_params))
        self._mu = NumpyActor(self.actor)
        self.o_norm, self.g_norm = o_norm, g_norm
        self.version = int(version)

    def load(self, weights: PolicyWeights) -> None:
        """`load_weights` from a `PolicyWeights`."""
        self.load_weights(weights.actor, weights.o_stats, weights.g_stats, weights.version)

    def weights(self) -> PolicyWeights:
        """Current weights as plain numpy arrays (copies)."""
        return PolicyWeights(
            version=self.version,
            actor=to_arrays(self.actor),
            o_stats=self.o_norm.state_dict(),
            g_stats=self.g_norm.state_dict(),
        )


def explore_actions(
    a: np.ndarray,
    *,
    rng: np.random.Generator,
    max_action: float,
    noise_eps: float,
    random_eps: float,
) -> np.ndarray:
    """The reference's exploration applied to deterministic actions a (n, action_dim)."""
    noise = rng.standard_normal(a.shape)
    u = rng.uniform(-max_action, max_action, size=a.shape)
    replace = rng.binomial(1, random_eps, size=(a.shape[0], 1))
    a = np.clip(a + noise_eps * max_action * noise, -max_action, max_action)
    return a + replace * (u - a)
