"""The actors' builder: the one reader of `HercsConfig` in hercs.actors.

It unpacks a joined run's config into what the actor and the evaluator processes run (policy,
envs, weights decoder, inserter, weights schedule), each of which takes explicit arguments;
the two shells (actor_shell.py, evaluator.py) ask it for parts and for their own few settings.
Every seed is derived here from `run.seed` and the process's identity, so that a part built
twice for one identity is the same part.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hercs.actors.inserter import Inserter
from hercs.actors.rollout import RolloutWorker, VectorRollout
from hercs.actors.weights import WeightsDecoder
from hercs.actors.weights_schedule import WeightsSchedule
from hercs.config import HercsConfig
from hercs.rl.envs import make_env
from hercs.rl.policy import Policy
from hercs.rl.seeding import generator, int_seed
from hercs.rl.task_registry import TaskSpec


@dataclass(frozen=True)
class ShellSettings:
    """What the actor's and the evaluator's process shells themselves need of the config."""

    run: str
    method: str
    spec: TaskSpec
    episodes_per_cycle: int
    """`training.episodes_per_cycle`: lockstep refuses an actor's surplus over it."""
    eval_episodes: int
    epochs: int
    """`training.epochs`: the evaluator refuses a request for a later epoch, whose goals it
    would have to skip to."""
    max_message_bytes: int
    """`replay.max_message_bytes`: the largest message a subscription parses."""


class ActorBuilder:
    def __init__(self, config: HercsConfig) -> None:
        self._config = config

    @property
    def shell(self) -> ShellSettings:
        config = self._config
        return ShellSettings(run=config.run.name, method=config.run.method,
                             spec=config.task.spec,
                             episodes_per_cycle=config.training.episodes_per_cycle,
                             eval_episodes=config.training.eval_episodes,
                             epochs=config.training.epochs,
                             max_message_bytes=config.replay.max_message_bytes)

    def _policy(self, seed: int) -> Policy:
        return Policy(spec=self._config.task.spec, config=self._config.ddpg, seed=seed)

    def decoder(self) -> WeightsDecoder:
        """A decoder that checks weights against a scratch policy of this run's sizes."""
        return WeightsDecoder(scratch=self._policy(0),
                              max_bytes=self._config.replay.max_message_bytes)

    # -- the actor ---------------------------------------------------------------------------
    def actor_policy(self, ident: str) -> Policy:
        return self._policy(int_seed(self._config.run.seed, "actor", ident))

    def exploration_rng(self, ident: str) -> np.random.Generator:
        return generator(self._config.run.seed, "actor", ident)

    def actor_envs(self, ident: str) -> VectorRollout:
        """`actor.envs_per_process` envs, env i seeded from (seed, "actor", ident, i); env 0
        keeps the seed a one-env actor had."""
        spec, seed, n = self._config.task.spec, self._config.run.seed, \
            self._config.actor.envs_per_process
        return VectorRollout(
            spec=spec, envs=[make_env(spec) for _ in range(n)],
            seeds=[int_seed(seed, "actor", ident, "env", *([str(i)] if i else []))
                   for i in range(n)])

    def inserter(self, *, request: Callable[[bytes, float], bytes], actor_id: str,
                 on_crash: Callable[[str, BaseException], None]) -> Inserter:
        """An inserter whose each send is `request(payload, actor.insert_timeout_s)`."""
        actor = self._config.actor
        timeout_s = actor.insert_timeout_s
        return Inserter(send=lambda payload: request(payload, timeout_s), actor_id=actor_id,
                        capacity=actor.insert_queue * actor.envs_per_process,
                        on_crash=on_crash)

    def schedule(self) -> WeightsSchedule:
        training = self._config.training
        return WeightsSchedule(schedule=training.schedule,
                               max_policy_lag=training.max_policy_lag)

    # -- the evaluator -----------------------------------------------------------------------
    def evaluator_policy(self) -> Policy:
        return self._policy(int_seed(self._config.run.seed, "evaluator", "policy"))

    def evaluator_env(self) -> RolloutWorker:
        spec = self._config.task.spec
        return RolloutWorker(spec=spec, env=make_env(spec),
                             seed=int_seed(self._config.run.seed, "evaluator"))
