"""How a run's replay admits inserts and samples, built from its config: the sample-to-insert
rate limiter (which only counts in lockstep), the lockstep gate (None in the asynchronous
schedule) and the policy-lag bound (`training.max_policy_lag`; None: no bound).
"""

from __future__ import annotations

from hercs.config import HercsConfig
from hercs.replay_service.lag_bound import PolicyLagBound
from hercs.replay_service.lockstep import LOCKSTEP_CLUSTER_WAIT_S, LockstepGate
from hercs.replay_service.rate_limiter import SampleToInsertRatio


def admission_for(config: HercsConfig
                  ) -> tuple[SampleToInsertRatio, LockstepGate | None, PolicyLagBound | None]:
    """(limiter, lockstep gate or None, lag bound or None) for `config`."""
    lockstep = config.training.schedule == "lockstep"
    gate = LockstepGate(
        episodes_per_cycle=config.training.episodes_per_cycle,
        fgb_size=config.cluster.fgb_size if config.run.uses_clusters else None,
        cluster_wait_s=LOCKSTEP_CLUSTER_WAIT_S) if lockstep else None
    lag_bound = (PolicyLagBound(max_lag=config.training.max_policy_lag)
                 if not lockstep and config.training.max_policy_lag >= 1 else None)
    limiter = SampleToInsertRatio(
        samples_per_insert=config.training.updates_per_episode,
        min_size_to_sample=config.replay.min_episodes_to_sample,
        error_buffer=config.replay.rate_tolerance_updates,
        max_request=config.training.minibatches_per_cycle,
        free_run=config.replay.free_run or lockstep,
    )
    return limiter, gate, lag_bound
