"""The four sampling methods, defined once: each is HER with or without cluster-balanced
episode shares (HER-CS) and with or without energy-based prioritisation (HER-EBP). The
replay's sampler (the row `sampler` names in hercs.replay_service.samplers.SAMPLERS), the
clusterer's role, the CLI's choices and the plots' labels all derive from this table."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Method:
    name: str
    """As typed on the command line and stored in `run.method`."""
    label: str
    """As the paper writes it (plots, tables)."""
    cluster_balanced: bool
    """Episodes are drawn in equal shares from the clusters of their final achieved goal
    (k-means fitted on failed goals by the clusterer)."""
    energy_prioritised: bool
    """Episodes are drawn in proportion to their trajectory energy (within a cluster when
    also cluster-balanced)."""
    sampler: str
    """The replay's sampler: a row of hercs.replay_service.samplers.SAMPLERS (its class and
    the config values it is built from)."""


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("her", "HER", cluster_balanced=False, energy_prioritised=False,
           sampler="uniform"),
    Method("her-cs", "HER-CS", cluster_balanced=True, energy_prioritised=False,
           sampler="cluster-balanced"),
    Method("her-ebp", "HER-EBP", cluster_balanced=False, energy_prioritised=True,
           sampler="energy"),
    Method("her-ebp-cs", "HER-EBP-CS", cluster_balanced=True, energy_prioritised=True,
           sampler="energy-cluster"),
)}
"""In the paper's order."""
