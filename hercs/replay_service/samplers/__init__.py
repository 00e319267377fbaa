"""Episode samplers, one strategy per module, and the one that serves each method."""

from __future__ import annotations

from hercs.config import HercsConfig
from hercs.errors import ConfigError
from hercs.replay_service.samplers.base import EpisodeSampler, SampleInfo, SampleSource
from hercs.replay_service.samplers.cluster_balanced import ClusterBalancedSampler
from hercs.replay_service.samplers.energy_cluster import EnergyClusterSampler
from hercs.replay_service.samplers.energy_prioritised import EnergySampler
from hercs.replay_service.samplers.uniform import UniformSampler
from hercs.rl.methods import METHODS

__all__ = [
    "ClusterBalancedSampler",
    "EnergyClusterSampler",
    "EnergySampler",
    "EpisodeSampler",
    "SampleInfo",
    "SampleSource",
    "UniformSampler",
    "make_sampler",
]


def make_sampler(method: str, config: HercsConfig) -> EpisodeSampler:
    """The episode sampler of `method` (hercs.rl.methods: cluster-balanced and/or
    energy-prioritised), built from config."""
    try:
        spec = METHODS[method]
    except KeyError:
        raise ConfigError(
            f"run.method: got {method!r}, must be one of {list(METHODS)}") from None
    k, repeat, eps = config.cluster.k, config.cluster.small_cluster_repeat, config.energy_epsilon
    exponent, rule = config.energy.exponent, config.cluster.share_rule
    if spec.cluster_balanced and spec.energy_prioritised:
        return EnergyClusterSampler(k, epsilon=eps, small_cluster_repeat=repeat,
                                    exponent=exponent, cluster_fill=config.energy.cluster_fill,
                                    share_rule=rule)
    if spec.cluster_balanced:
        return ClusterBalancedSampler(k, small_cluster_repeat=repeat, share_rule=rule)
    if spec.energy_prioritised:
        return EnergySampler(epsilon=eps, num_clusters=k, exponent=exponent)
    return UniformSampler(num_clusters=k)
