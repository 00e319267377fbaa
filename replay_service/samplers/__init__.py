"""Episode samplers, one strategy per module, and the method → sampler table."""

from __future__ import annotations

from collections.abc import Callable

from hercs.config import HercsConfig
from hercs.errors import ConfigError
from replay_service.samplers.base import EpisodeSampler, SampleInfo, SampleSource
from replay_service.samplers.cluster_balanced import ClusterBalancedSampler
from replay_service.samplers.energy import EnergySampler
from replay_service.samplers.energy_cluster import EnergyClusterSampler
from replay_service.samplers.uniform import UniformSampler

__all__ = [
    "SAMPLERS",
    "ClusterBalancedSampler",
    "EnergyClusterSampler",
    "EnergySampler",
    "EpisodeSampler",
    "SampleInfo",
    "SampleSource",
    "UniformSampler",
    "make_sampler",
]

SAMPLERS: dict[str, Callable[[HercsConfig], EpisodeSampler]] = {
    # keys = hercs.config.METHODS (a unit test holds them equal)
    "her": lambda c: UniformSampler(num_clusters=c.cluster.k),
    "her-cs": lambda c: ClusterBalancedSampler(
        c.cluster.k, small_cluster_repeat=c.cluster.small_cluster_repeat
    ),
    "her-ebp": lambda c: EnergySampler(epsilon=c.energy.epsilon, num_clusters=c.cluster.k),
    "her-ebp-cs": lambda c: EnergyClusterSampler(
        c.cluster.k,
        epsilon=c.energy.epsilon,
        small_cluster_repeat=c.cluster.small_cluster_repeat,
    ),
}


def make_sampler(method: str, config: HercsConfig) -> EpisodeSampler:
    """The episode sampler of `method` (her, her-cs, her-ebp, her-ebp-cs), built from config."""
    try:
        factory = SAMPLERS[method]
    except KeyError:
        raise ConfigError(
            f"run.method: got {method!r}, must be one of {sorted(SAMPLERS)}"
        ) from None
    return factory(config)
