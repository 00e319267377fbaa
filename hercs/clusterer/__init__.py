"""The clusterer service: failed-goal buffer, k-means refits, publishes the cluster model.

`hercs.clusterer.clusterer_core.Clusterer` is the pure core (no Zenoh); the service module wraps it.
"""

from hercs.clusterer.clusterer_core import Clusterer
from hercs.clusterer.failed_goals import FailedGoalBuffer
from hercs.clusterer.kmeans import fit_cluster_model

__all__ = ["Clusterer", "FailedGoalBuffer", "fit_cluster_model"]
