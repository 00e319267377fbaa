"""hercs: Hindsight Experience Replay with Cluster-based Sampling, as distributed services.

The Python API (`hercs.api`; README "Python API"): `load_policy`, `read_metrics`,
`read_episodes`, `load_config`.
"""

from hercs.api import (
    LoggedEpisode,
    Metrics,
    ObservationError,
    TrainedPolicy,
    load_config,
    load_policy,
    read_episodes,
    read_metrics,
)
from hercs.errors import ConfigError, HercsError

__version__ = "0.1.0"

__all__ = [
    "ConfigError", "HercsError", "LoggedEpisode", "Metrics", "ObservationError",
    "TrainedPolicy", "__version__", "load_config", "load_policy", "read_episodes",
    "read_metrics",
]
