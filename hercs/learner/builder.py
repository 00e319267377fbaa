"""The learner's builder: the one reader of `HercsConfig` in hercs.learner.

It unpacks the config into the parts the learner process runs (the DDPG learner, the loop,
the prefetcher, the replay-status client, the evaluation requests and the policy keeper),
each of which takes explicit arguments, as Acme's builders do for their learners. The shell
(learner_shell.py) asks it for parts and for the few settings of its own; tests and tools
that want a part build it here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hercs.config import HercsConfig
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.evaluations import EvalRequests, PolicyKeeper
from hercs.learner.loop import LearnerLoop
from hercs.learner.prefetch import ASK_AGAIN_S, BatchShape, Prefetcher
from hercs.learner.replay_status import ReplayStatusClient
from hercs.net.service_shell import ServiceRuntime
from hercs.wire.served import ReplayCounters


@dataclass(frozen=True)
class ShellSettings:
    """What the learner's process shell itself needs of the config."""

    epochs: int
    cycles_per_epoch: int
    eval_wait_s: float
    """`training.eval_wait_s`: how long the run waits for its last evaluations."""
    device_request: str
    """`learner.device` as asked ("auto", "cpu", "cuda:0"): logged beside the device used."""
    config_record: dict[str, Any]
    """The resolved config as a dict: saved in each checkpoint and policy file."""


class LearnerBuilder:
    def __init__(self, config: HercsConfig) -> None:
        self._config = config

    @property
    def shell(self) -> ShellSettings:
        training = self._config.training
        return ShellSettings(epochs=training.epochs,
                             cycles_per_epoch=training.cycles_per_epoch,
                             eval_wait_s=training.eval_wait_s,
                             device_request=self._config.learner.device,
                             config_record=self._config.to_dict())

    def learner(self) -> DDPGLearner:
        config = self._config
        settings = config.learner
        return DDPGLearner(spec=config.task.spec, config=config.ddpg, seed=config.run.seed,
                           device=settings.device, precision=settings.precision,
                           parallel_halves=settings.parallel_halves,
                           cuda_graph=settings.cuda_graph)

    def loop(self, learner: DDPGLearner, *,
             replay_status: Callable[[int], ReplayCounters]) -> LearnerLoop:
        training = self._config.training
        return LearnerLoop(learner=learner, epochs=training.epochs,
                           cycles_per_epoch=training.cycles_per_epoch,
                           clusters=self._config.cluster.k, replay_status=replay_status)

    def replay_status(self, runtime: ServiceRuntime) -> ReplayStatusClient:
        replay = self._config.replay
        return ReplayStatusClient(runtime, timeout_s=min(replay.sample_timeout_s, ASK_AGAIN_S),
                                  max_bytes=replay.max_message_bytes)

    def eval_requests(self) -> EvalRequests:
        return EvalRequests(resend_s=self._config.training.eval_resend_s)

    def keeper(self, *, best_success: float | None) -> PolicyKeeper:
        return PolicyKeeper(every=self._config.training.checkpoint_every,
                            best_success=best_success)

    def batch_shape(self) -> BatchShape:
        config = self._config
        return BatchShape(run=config.run.name, spec=config.task.spec, clusters=config.cluster.k,
                          minibatches=config.training.minibatches_per_cycle,
                          batch_size=config.ddpg.batch_size)

    def prefetcher(self, runtime: ServiceRuntime, *, version: Callable[[], int],
                   samples_kept: int) -> Prefetcher:
        config = self._config
        return Prefetcher(runtime=runtime, shape=self.batch_shape(),
                          lockstep=config.training.schedule == "lockstep",
                          depth=config.learner.prefetch_depth,
                          sample_timeout_s=config.replay.sample_timeout_s,
                          version=version, samples_kept=samples_kept)
