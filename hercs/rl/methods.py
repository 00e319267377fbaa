"""The sampling methods, one row each: its name, its label and its sampler. What a method
needs (cluster models, trajectory energy) is its sampler's `needs`, which the clusterer, the
lockstep gate, the config's checks and the plots read; a new method is a sampler module
(hercs.rl.samplers) plus one row here."""

from __future__ import annotations

from dataclasses import dataclass

from hercs.errors import ConfigError
from hercs.rl.samplers import (
    ClusterBalancedSampler,
    EnergyClusterSampler,
    EnergyPrioritisedSampler,
    EpisodeSampler,
    Needs,
    SamplerSettings,
    UniformSampler,
)


@dataclass(frozen=True)
class Method:
    name: str
    """As typed on the command line and stored in `run.method`."""
    label: str
    """As the paper writes it (plots, tables)."""
    sampler: type[EpisodeSampler]
    """The replay's episode sampler: its class, built by `from_settings`."""

    @property
    def needs(self) -> Needs:
        return self.sampler.needs


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("her", "HER", UniformSampler),
    Method("her-cs", "HER-CS", ClusterBalancedSampler),
    Method("her-ebp", "HER-EBP", EnergyPrioritisedSampler),
    Method("her-ebp-cs", "HER-EBP-CS", EnergyClusterSampler),
)}
"""In the paper's order: HER, then with cluster-balanced shares (HER-CS), with energy-based
prioritisation (HER-EBP), and with both."""


def method(name: str) -> Method:
    """The row of `name`; ConfigError naming the choices if there is none."""
    try:
        return METHODS[name]
    except KeyError:
        raise ConfigError(f"run.method: got {name!r}, must be one of {list(METHODS)}") from None


def make_sampler(name: str, settings: SamplerSettings) -> EpisodeSampler:
    """The episode sampler of method `name`, built from the run's settings."""
    return method(name).sampler.from_settings(settings)
