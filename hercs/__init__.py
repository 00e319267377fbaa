"""hercs: Hindsight Experience Replay with Cluster-based Sampling, as distributed services."""

__version__ = "0.1.0"
