"""The algorithm's sections of the config tree (hercs.config): DDPG, HER, the clusters and the
energy prioritisation. Every default equals the paper's reference value (docs/DESIGN.md §4);
the sources are named as in hercs.config."""

from __future__ import annotations

from dataclasses import dataclass, field

from hercs.config.checks import _check, _positive, _unit_interval
from hercs.config.unsaved import UNSAVED
from hercs.rl.samplers.share_rules import SHARE_RULES


@dataclass
class DDPGConfig:
    hidden_size: int = 256
    """Units per hidden layer of actor and critic [HER-py]."""
    hidden_layers: int = 3
    """Hidden ReLU layers of actor and critic [HER-py]."""
    lr_actor: float = 1e-3
    """Adam learning rate of the actor [HER-py]."""
    lr_critic: float = 1e-3
    """Adam learning rate of the critic [HER-py]."""
    gamma: float = 0.98
    """Discount [HER-py]."""
    polyak: float = 0.95
    """Target nets: θ' ← polyak·θ' + (1−polyak)·θ, once per cycle [HER-py]."""
    action_l2: float = 1.0
    """Weight of the actor's (a/max_action)² penalty [HER-py]."""
    clip_return: bool = True
    """Clip the critic target to [−1/(1−γ), 0] [HER-py]."""
    batch_size: int = 256
    """Transitions per minibatch [HER-py]."""
    noise_eps: float = 0.2
    """Gaussian exploration noise, times max_action [HER-py]."""
    random_eps: float = 0.3
    """Probability of a uniformly random action while exploring [HER-py]."""
    clip_obs: float = 200.0
    """Observations and goals are clipped to ±clip_obs before normalising [HER-py]."""
    norm_clip: float = 5.0
    """Normalised inputs are clipped to ±norm_clip [HER-py]."""
    norm_eps: float = 0.01
    """Floor of the normaliser's standard deviation [HER-py]."""

    def __post_init__(self) -> None:
        for name in ("hidden_size", "hidden_layers", "batch_size"):
            _check(getattr(self, name) >= 1, f"ddpg.{name}", getattr(self, name), "be >= 1")
        for name in ("lr_actor", "lr_critic"):
            # Adam moves each weight by about lr per step: past 1 it leaves any sensible scale
            _check(0 < getattr(self, name) <= 1, f"ddpg.{name}", getattr(self, name),
                   "lie in (0, 1]")
        for name in ("clip_obs", "norm_clip", "norm_eps"):
            _positive(f"ddpg.{name}", getattr(self, name))
        _unit_interval("ddpg.gamma", self.gamma, closed=False)
        _unit_interval("ddpg.polyak", self.polyak)
        _unit_interval("ddpg.random_eps", self.random_eps)
        _check(self.action_l2 >= 0, "ddpg.action_l2", self.action_l2, "be >= 0")
        _check(self.noise_eps >= 0, "ddpg.noise_eps", self.noise_eps, "be >= 0")


@dataclass
class HERConfig:
    replay_k: int = 4
    """Relabel ratio: a sampled transition gets a future goal with p = 1 − 1/(1+k) [HER-py]."""

    def __post_init__(self) -> None:
        _check(self.replay_k >= 0, "her.replay_k", self.replay_k, "be >= 0")

    @property
    def future_p(self) -> float:
        return 1.0 - 1.0 / (1.0 + self.replay_k)


@dataclass
class ClusterConfig:
    k: int = 8
    """Number of k-means clusters of failed goals [HER-CS]."""
    fgb_size: int = 150
    """How many goals the FGB holds, the paper's failed-goal buffer: the desired goals of the
    last `fgb_size` failed episodes, which the clusterer fits its k clusters to; it refits
    each time all of them have been replaced by newer ones [HER-CS]."""
    small_cluster_repeat: int = 4
    """A cluster with fewer than share/repeat episodes contributes each member ~repeat times
    and fills the rest of its share uniformly [HER-CS]."""
    kmeans_n_init: int = 10
    """k-means restarts per refit (scikit-learn; seeded)."""
    share_rule: str = "every-cluster"
    """Which clusters share a batch (a row of hercs.rl.samplers.share_rules.SHARE_RULES):
    `every-cluster` (each of the k gets ⌊B/k⌋) or `reference` (the reference code's: the
    clusters up to the highest label in the buffer, so empty top clusters give their shares
    to the others) [HER-CS]."""

    def __post_init__(self) -> None:
        _check(self.k >= 1, "cluster.k", self.k, "be >= 1")
        _check(self.fgb_size >= self.k, "cluster.fgb_size", self.fgb_size, f"be >= k={self.k}")
        _check(self.small_cluster_repeat >= 1, "cluster.small_cluster_repeat",
               self.small_cluster_repeat, "be >= 1")
        _check(self.kmeans_n_init >= 1, "cluster.kmeans_n_init", self.kmeans_n_init, "be >= 1")
        _check(self.share_rule in SHARE_RULES, "cluster.share_rule", self.share_rule,
               f"be one of {list(SHARE_RULES)}")


EPSILON_V1 = 1e-6
"""EBP's ε on the authors' simulator (Fetch*-v1, MuJoCo 2.1): the trembling of a resting
object gives every episode ~1e-3 of energy there already."""
EPSILON_MUJOCO3 = 1e-3
"""EBP's ε on MuJoCo 3 (v4 and every gymnasium task), where a resting object has 4e-6–4e-5:
the floor v1's simulator gives, which brings v4's HER-EBP and HER-EBP-CS to the authors'
(docs/DESIGN.md §9.3)."""


def default_energy_epsilon(env_version: str) -> float:
    """energy.epsilon where a config leaves it unset, by `task.env_version`."""
    return EPSILON_V1 if env_version == "v1" else EPSILON_MUJOCO3


@dataclass
class EnergyConfig:
    clip_energy: float = 0.5
    """Per-transition energy clip; the reference's PickAndPlace setting, used for every task
    [EBP]."""
    mass: float = 1.0
    """Object mass m in the potential and kinetic terms [EBP]."""
    gravity: float = 9.81
    """g in the potential term m·g·(z_t − z_0) [EBP]."""
    delta_t: float = 0.04
    """Time between env steps, for velocities Δag/Δt [EBP]."""
    w_potential: float = 1.0
    """Weight of the potential energy [EBP]."""
    w_kinetic: float = 1.0
    """Weight of the kinetic energy [EBP]."""
    w_rotational: float = 1.0
    """Weight of the rotational energy (hand manipulation tasks only) [EBP]."""
    inertia: float = 1.0
    """Moment of inertia I in the rotational term ½·I·‖Δθ/Δt‖² (hand tasks only) [EBP]."""
    epsilon: float | None = field(default=None, metadata={UNSAVED: EPSILON_V1})
    """Added to every trajectory energy so no episode has p = 0. Unset (null), the simulator's
    own (`default_energy_epsilon`): 1e-3 on MuJoCo 3 (v4 and every gymnasium task), 1e-6 on
    the authors' v1, whose resting cube trembles with ~1e-3 of energy of its own; a run saves
    the value it used (docs/DESIGN.md §9.3), and one whose saved config has no such field ran
    with 1e-6, on every simulator [DESIGN]."""
    temperature: float = 0.99
    """p ∝ e^(1/(temperature + 0.01)) + ε, the reference's form: 0.99 makes the exponent 1
    (p ∝ e + ε, docs/DESIGN.md §4); the reference's default temperature 1 gives 0.990 [EBP]."""
    cluster_fill: str = "energy"
    """HER-EBP-CS inside a cluster: draw its members by energy (`energy`, our definition) or
    uniformly (`uniform`, HER-CS's draw with EBP only in the whole-buffer fills) [DESIGN]."""

    def __post_init__(self) -> None:
        for name in ("clip_energy", "mass", "gravity", "delta_t", "temperature", "inertia"):
            _positive(f"energy.{name}", getattr(self, name))
        if self.epsilon is not None:
            _positive("energy.epsilon", self.epsilon)
        _check(self.cluster_fill in ("energy", "uniform"), "energy.cluster_fill",
               self.cluster_fill, "be energy or uniform")
        for name in ("w_potential", "w_kinetic", "w_rotational"):
            _check(getattr(self, name) >= 0, f"energy.{name}", getattr(self, name), "be >= 0")

    @property
    def exponent(self) -> float:
        """The power the trajectory energies are raised to before ε is added."""
        return 1.0 / (self.temperature + 0.01)
