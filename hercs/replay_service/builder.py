"""The replay's builder: the one reader of `HercsConfig` in hercs.replay_service.

It unpacks the config into the table's parts (store, sampler, normalisers, policy-lag ledger,
rate limiter and the schedule's admission), each of which takes explicit arguments, and into
the table that owns them, as Acme's builders make Reverb's tables. The shell (replay_shell.py)
asks it for the table, opened on the run's episode log, and for its own few settings; tests,
benches and studies that want an in-process table build it here (`table`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from hercs.config import HercsConfig, load_yaml
from hercs.errors import ConfigError
from hercs.replay_service.admission import Admission, AsynchronousAdmission
from hercs.replay_service.lag_bound import PolicyLagBound
from hercs.replay_service.lockstep import LOCKSTEP_CLUSTER_WAIT_S, LockstepAdmission
from hercs.replay_service.normalizers import EpisodeNormalizers
from hercs.replay_service.policy_lag import PolicyLagLedger
from hercs.replay_service.rate_limiter import SampleToInsertRatio
from hercs.replay_service.replay_recovery import open_table
from hercs.replay_service.store import EpisodeStore
from hercs.replay_service.table import EpisodeLogSink, ReplayTable
from hercs.rl.methods import make_sampler
from hercs.rl.seeding import generator, int_seed
from hercs.rl.task_registry import TaskSpec
from hercs.run.runlog import RecoveringLogWriter

log = logging.getLogger("hercs.replay")


@dataclass(frozen=True)
class ShellSettings:
    """What the replay's process shell itself needs of the config."""

    run: str
    task: str
    """`task.name` as configured (for the start-up line)."""
    method: str
    spec: TaskSpec
    clusters: int
    """`cluster.k`: a published cluster model must have as many centroids."""
    max_message_bytes: int
    insert_timeout_s: float
    """`actor.insert_timeout_s`: an insert still parked after it is answered `expired`."""
    sample_timeout_s: float
    insert_workers: int
    config_yaml: bytes
    """The resolved config, as the replay serves it to the processes that join the run."""


class ReplayBuilder:
    def __init__(self, config: HercsConfig) -> None:
        self._config = config

    @property
    def shell(self) -> ShellSettings:
        config = self._config
        replay = config.replay
        return ShellSettings(
            run=config.run.name, task=config.task.name, method=config.run.method,
            spec=config.task.spec, clusters=config.cluster.k,
            max_message_bytes=replay.max_message_bytes,
            insert_timeout_s=config.actor.insert_timeout_s,
            sample_timeout_s=replay.sample_timeout_s, insert_workers=replay.insert_workers,
            config_yaml=yaml.safe_dump(config.to_dict(), sort_keys=False).encode())

    def store(self) -> EpisodeStore:
        config = self._config
        return EpisodeStore(capacity_episodes=config.capacity_episodes, spec=config.task.spec,
                            eviction=config.replay.eviction,
                            eviction_seed=int_seed(config.run.seed, "replay", "eviction"))

    def normalizers(self) -> EpisodeNormalizers:
        spec, ddpg = self._config.task.spec, self._config.ddpg
        return EpisodeNormalizers(obs_dim=spec.obs_dim, goal_dim=spec.goal_dim,
                                  eps=ddpg.norm_eps, clip_range=ddpg.norm_clip,
                                  clip_obs=ddpg.clip_obs, future_p=self._config.her.future_p)

    def lags(self) -> PolicyLagLedger:
        return PolicyLagLedger(self._config.training.episodes_per_cycle,
                               prefetch_depth=self._config.learner.prefetch_depth)

    def admission(self, lags: PolicyLagLedger) -> tuple[SampleToInsertRatio, Admission]:
        """(the sample-to-insert limiter, the schedule's admission); in lockstep the limiter
        runs free and only counts."""
        config = self._config
        training, replay = config.training, config.replay
        lockstep = training.schedule == "lockstep"
        limiter = SampleToInsertRatio(
            samples_per_insert=training.updates_per_episode,
            min_size_to_sample=replay.min_episodes_to_sample,
            error_buffer=replay.rate_tolerance_updates,
            max_request=training.minibatches_per_cycle,
            free_run=replay.free_run or lockstep)
        if lockstep:
            return limiter, LockstepAdmission(
                episodes_per_cycle=training.episodes_per_cycle,
                fgb_size=config.cluster.fgb_size if config.run.uses_clusters else None,
                cluster_wait_s=LOCKSTEP_CLUSTER_WAIT_S)
        lag_bound = (PolicyLagBound(max_lag=training.max_policy_lag)
                     if training.max_policy_lag >= 1 else None)
        return limiter, AsynchronousAdmission(limiter=limiter, lags=lags, lag_bound=lag_bound)

    def table(self, *, rng: np.random.Generator, log: EpisodeLogSink | None = None,
              clock: Callable[[], float] = time.monotonic) -> ReplayTable:
        """An empty table of this run; `log` None: one that logs nothing (in-process)."""
        config = self._config
        lags = self.lags()
        limiter, admission = self.admission(lags)
        return ReplayTable(
            spec=config.task.spec, store=self.store(),
            sampler=make_sampler(config.run.method, config.sampler_settings),
            normalizers=self.normalizers(), lags=lags, limiter=limiter, admission=admission,
            energy=config.energy, clusters=config.cluster.k, future_p=config.her.future_p,
            failed_goals_kept=config.cluster.fgb_size,
            waiting_inserts_per_actor=config.replay.waiting_inserts_per_actor,
            rng=rng, log=log, clock=clock)

    def open_table(self, run_dir: Path) -> tuple[RecoveringLogWriter, ReplayTable]:
        """The run's episode log, open for appending, and the table holding what it logged
        (hercs.replay_service.replay_recovery)."""
        config = self._config
        replay = config.replay
        rng = generator(config.run.seed, "replay")
        return open_table(
            run_dir, run=config.run.name, spec=config.task.spec, scene=replay.log_scene,
            segment_episodes=replay.log_segment_episodes(config.capacity_episodes),
            max_bytes=replay.log_max_bytes,
            new_table=lambda episode_log: self.table(rng=rng, log=episode_log))


def saved_epsilon(config: HercsConfig, saved: Path) -> HercsConfig:
    """`config` with the ε written out: where it leaves ε unset and the run saved a config
    with a number, that number (a compose run resumed with HERCS_RESUME rebuilds its config
    from flags, and a run made before v4's default ε changed must keep its own), else its
    environment's default. The replay resolves the config it serves with it."""
    if config.energy.epsilon is None and saved.is_file():
        try:
            epsilon = load_yaml(saved).energy_epsilon
        except (ConfigError, OSError) as exc:
            log.warning("%s: not read for its energy.epsilon (%s); using the default", saved,
                        exc)
        else:
            return replace(config, energy=replace(config.energy, epsilon=epsilon))
    return config.resolved()
