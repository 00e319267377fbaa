"""The clusterer's pure core: classify episodes, keep the failed goals, refit k-means.

An episode failed if it did not succeed (by `is_success`, or as its caller says); its desired
goal then goes
into the failed-goal buffer. When the buffer has been entirely replaced since the last fit,
k-means is refitted (refit `v` seeded with `int_seed(seed, "clusterer", "kmeans", str(v))`) and
a new `ClusterModel` returned.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hercs.clusterer.failed_goals import FailedGoalBuffer
from hercs.clusterer.kmeans import fit_cluster_model
from hercs.config import ClusterConfig
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.seeding import int_seed

GoalSuccess = Callable[[np.ndarray, np.ndarray], object]
"""(final achieved goal, desired goal) → truthy when the episode succeeded (a task's
`TaskSpec.is_success`)."""


class Clusterer:
    """Turns a stream of (final achieved goal, desired goal) pairs into cluster models."""

    def __init__(self, *, config: ClusterConfig, seed: int, goal_dim: int,
                 is_success: GoalSuccess | None) -> None:
        """`is_success` judges each observed episode; None when every caller of `observe`
        says whether its episode succeeded (an env whose info carries the flag)."""
        self.config = config
        self.seed = int(seed)
        self.is_success = is_success
        self.fgb = FailedGoalBuffer(config.fgb_size, goal_dim=goal_dim)
        self.episodes_seen = 0
        """Episodes observed (successes and failures)."""
        self.failures_seen = 0
        """Episodes observed that failed (each put its goal into the buffer)."""
        self.model: ClusterModel | None = None
        """Latest fitted model (None before the first fit); republished to late joiners."""
        self.last_version = 0
        """Version of the run's latest model, this process's or an earlier one's (`resume`)."""

    def resume(self, *, failed_goals: np.ndarray, failures_seen: int, episodes_seen: int,
               model_version: int) -> None:
        """Continue a run an earlier clusterer process served: its newest failed goals refill
        the buffer (oldest first), the counts continue, and the next model gets version
        `model_version + 1`. If a model exists it was fitted on about these goals, so the
        next fit waits for a buffer of new failures, as it would have."""
        for goal in np.asarray(failed_goals, np.float64).reshape(-1, self.fgb.goal_dim):
            self.fgb.add(goal)
        if model_version > 0:
            self.fgb.mark_fitted()
        self.fgb.total_added = int(failures_seen)
        self.failures_seen = int(failures_seen)
        self.episodes_seen = int(episodes_seen)
        self.last_version = int(model_version)

    def observe(self, *, final_ag: np.ndarray, desired_goal: np.ndarray,
                succeeded: bool | None = None) -> ClusterModel | None:
        """Account for one stored episode; return a new model if this episode triggered a refit.

        final_ag is ag_T (the achieved goal after the last step), desired_goal is g;
        `succeeded` overrides `is_success` where the caller knows the outcome.
        """
        final_ag = np.asarray(final_ag, dtype=np.float64)
        desired_goal = np.asarray(desired_goal, dtype=np.float64)
        if final_ag.shape != desired_goal.shape:
            raise ValueError(f"Clusterer.observe: final_ag {final_ag.shape} and desired_goal "
                             f"{desired_goal.shape} must have the same shape")
        if not (np.all(np.isfinite(final_ag)) and np.all(np.isfinite(desired_goal))):
            raise ValueError("Clusterer.observe: final_ag or desired_goal holds NaN or Inf")
        if succeeded is None:
            if self.is_success is None:
                raise ValueError("Clusterer.observe: no is_success to judge the episode by; "
                                 "pass succeeded=")
            succeeded = bool(self.is_success(final_ag, desired_goal))
        self.episodes_seen += 1
        if succeeded:
            return None
        self.failures_seen += 1
        self.fgb.add(desired_goal)
        if not self.fgb.refit_due:
            return None
        return self._refit()

    def _refit(self) -> ClusterModel:
        version = self.last_version + 1
        goals = self.fgb.goals()
        centroids = fit_cluster_model(
            goals,
            k=self.config.k,
            seed=int_seed(self.seed, "clusterer", "kmeans", str(version)),
            n_init=self.config.kmeans_n_init,
        )
        self.fgb.mark_fitted()
        self.model = ClusterModel(version=version, centroids=centroids, n_goals=len(goals),
                                  failures_seen=self.failures_seen)
        self.last_version = version
        return self.model
