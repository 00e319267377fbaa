"""hercs: Hindsight Experience Replay with Cluster-based Sampling, as distributed services.

The Python API (README "Python API"): `up` starts a run, `resume` continues a stopped one,
each returning a `Run` handle (`hercs.apps.cli.run_handle`); `load_policy`, `read_metrics`,
`read_episodes` and `load_config` read a run directory (`hercs.api`).
"""

from __future__ import annotations

from importlib import metadata as _metadata
from typing import TYPE_CHECKING, Any

from hercs.api import (
    LoggedEpisode,
    Metrics,
    MissingPackage,
    ObservationError,
    TrainedPolicy,
    load_config,
    load_policy,
    read_episodes,
    read_metrics,
)
from hercs.errors import ConfigError, HercsError

if TYPE_CHECKING:
    from hercs.apps.cli.run_handle import Run, resume, up

try:
    __version__ = _metadata.version("hercs")  # pyproject.toml's, as installed
except _metadata.PackageNotFoundError:  # a bare checkout on PYTHONPATH
    __version__ = "(not installed)"

__all__ = [
    "ConfigError", "HercsError", "LoggedEpisode", "Metrics", "MissingPackage", "ObservationError",
    "Run", "TrainedPolicy", "__version__", "load_config", "load_policy", "read_episodes",
    "read_metrics", "resume", "up",
]


def __getattr__(name: str) -> Any:
    """`up`, `resume` and `Run` on first use: the launcher's imports stay out of every
    service's `import hercs`. This module is the top of hercs' layers, above hercs.apps: no
    module of the package imports it (the import-linter contract "root-on-top" in
    pyproject.toml), so reaching down to the launcher here closes no cycle."""
    if name in ("up", "resume", "Run"):
        from hercs.apps.cli import run_handle

        return getattr(run_handle, name)
    raise AttributeError(f"module 'hercs' has no attribute {name!r}")
