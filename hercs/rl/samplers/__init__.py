"""Episode samplers, one strategy per module, each declaring what it needs (`Needs`) and how
it is built (`from_settings`); with them what they draw from (`SamplingIndex`) and the cluster
share rules. A new strategy is its module plus its method's row in hercs.rl.methods.

They sit in hercs.rl, below the config, because the config checks a method against what its
sampler needs and a share rule against `SHARE_RULES`; the replay service, the integrations and
the studies build them from there."""

from __future__ import annotations

from hercs.rl.samplers.base import (
    EpisodeSampler,
    Needs,
    SampleInfo,
    SamplerSettings,
    SampleSource,
)
from hercs.rl.samplers.cluster_balanced import ClusterBalancedSampler
from hercs.rl.samplers.energy_cluster import EnergyClusterSampler
from hercs.rl.samplers.energy_prioritised import EnergyPrioritisedSampler
from hercs.rl.samplers.uniform import UniformSampler

__all__ = [
    "ClusterBalancedSampler",
    "EnergyClusterSampler",
    "EnergyPrioritisedSampler",
    "EpisodeSampler",
    "Needs",
    "SampleInfo",
    "SampleSource",
    "SamplerSettings",
    "UniformSampler",
]
