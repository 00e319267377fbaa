"""Episode samplers, one strategy per module, and the table that builds each method's:
a new strategy is its module plus one row of `SAMPLERS` (and the method's row naming it)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hercs.config import HercsConfig
from hercs.errors import ConfigError
from hercs.replay_service.samplers.base import EpisodeSampler, SampleInfo, SampleSource
from hercs.replay_service.samplers.cluster_balanced import ClusterBalancedSampler
from hercs.replay_service.samplers.energy_cluster import EnergyClusterSampler
from hercs.replay_service.samplers.energy_prioritised import EnergySampler
from hercs.replay_service.samplers.uniform import UniformSampler
from hercs.rl.methods import METHODS

__all__ = [
    "SAMPLERS",
    "ClusterBalancedSampler",
    "EnergyClusterSampler",
    "EnergySampler",
    "EpisodeSampler",
    "SampleInfo",
    "SampleSource",
    "SamplerRow",
    "UniformSampler",
    "make_sampler",
]


@dataclass(frozen=True)
class SamplerRow:
    """A sampler class and the config values it is built from."""

    cls: Callable[..., EpisodeSampler]
    params: Callable[[HercsConfig], dict[str, Any]]


def _cluster_params(config: HercsConfig) -> dict[str, Any]:
    return dict(small_cluster_repeat=config.cluster.small_cluster_repeat,
                share_rule=config.cluster.share_rule)


SAMPLERS: dict[str, SamplerRow] = {
    "uniform": SamplerRow(UniformSampler, lambda c: dict(num_clusters=c.cluster.k)),
    "energy": SamplerRow(EnergySampler, lambda c: dict(
        epsilon=c.energy_epsilon, num_clusters=c.cluster.k, exponent=c.energy.exponent)),
    "cluster-balanced": SamplerRow(ClusterBalancedSampler, lambda c: dict(
        k=c.cluster.k, **_cluster_params(c))),
    "energy-cluster": SamplerRow(EnergyClusterSampler, lambda c: dict(
        k=c.cluster.k, epsilon=c.energy_epsilon, exponent=c.energy.exponent,
        cluster_fill=c.energy.cluster_fill, **_cluster_params(c))),
}
"""`Method.sampler` (hercs.rl.methods) → the row its replay builds."""


def make_sampler(method: str, config: HercsConfig) -> EpisodeSampler:
    """The episode sampler of `method`, built from config by its row of `SAMPLERS`."""
    try:
        row = SAMPLERS[METHODS[method].sampler]
    except KeyError:
        raise ConfigError(
            f"run.method: got {method!r}, must be one of {list(METHODS)}") from None
    return row.cls(**row.params(config))
