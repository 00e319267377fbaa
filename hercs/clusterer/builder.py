"""The clusterer's builder: the one reader of `HercsConfig` in hercs.clusterer.

It unpacks the config into the core the process runs (`Clusterer`, which takes the
`ClusterConfig` section and explicit arguments) and into the few settings of the shell
(clusterer_shell.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from hercs.clusterer.clusterer_core import Clusterer
from hercs.config import HercsConfig
from hercs.rl.task_registry import TaskSpec


@dataclass(frozen=True)
class ShellSettings:
    """What the clusterer's process shell itself needs of the config."""

    run: str
    method: str
    spec: TaskSpec
    fits: bool
    """The run's sampler reads cluster labels (`run.uses_clusters`): models are fitted and
    published; else the process only counts."""
    fgb_size: int
    """`cluster.fgb_size`: the most failed goals a replay's snapshot may hold."""
    clusters: int


class ClustererBuilder:
    def __init__(self, config: HercsConfig) -> None:
        self._config = config

    @property
    def shell(self) -> ShellSettings:
        config = self._config
        return ShellSettings(run=config.run.name, method=config.run.method,
                             spec=config.task.spec, fits=config.run.uses_clusters,
                             fgb_size=config.cluster.fgb_size, clusters=config.cluster.k)

    def core(self) -> Clusterer:
        config = self._config
        spec = config.task.spec
        return Clusterer(config=config.cluster, seed=config.run.seed, goal_dim=spec.goal_dim,
                         is_success=spec.is_success)
