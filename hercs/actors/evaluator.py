"""The evaluator process (`hercs evaluator`): deterministic test episodes of epoch-end policies.

Every `Weights` with `evaluate=True` is queued (FIFO, so newer weights never push an epoch's
policy out) and evaluated once, without noise, in the evaluator's own env, seeded once: every
method of one seed is tested on the same goals (docs/DESIGN.md §9.7), epoch e on the stream's
episodes after (e - 1) x eval_episodes, however often the evaluator restarted. Its
`EvalResult` must arrive, so the publisher blocks rather than drops, and each put first waits up to
`SUBSCRIBER_WAIT_S` for the learner to match: a put with no matched subscriber is lost. A stop
abandons an evaluation between episodes; no partial result is sent.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from dataclasses import dataclass

import numpy as np

from hercs.actors.builder import ActorBuilder
from hercs.config import HercsConfig
from hercs.errors import InvalidMessage
from hercs.net.service_shell import ServiceRuntime, service_main
from hercs.net.transport import Publisher, TransportError
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.rl.policy import PolicyWeights
from hercs.rl.task_registry import goal_distance
from hercs.run.warn_once import WarnOncePerMinute

log = logging.getLogger(__name__)

RESULTS_KEPT = 64
SUBSCRIBER_WAIT_S = 30.0
"""How long a result waits for a matching subscriber before it is published anyway."""
_POLL_S = 0.25


@dataclass(frozen=True)
class EvalRequest:
    epoch: int
    weights: PolicyWeights

    @property
    def key(self) -> tuple[int, int]:
        return (self.epoch, self.weights.version)


class EvalQueue:
    """FIFO of evaluation requests filled by the subscription threads.

    A request whose (epoch, weights version) is already queued or being evaluated is skipped:
    the late-joiner cache, and the learner asking again for an overdue evaluation, can hand
    over the same Weights twice. A request for one already evaluated is queued: the evaluator
    then publishes its cached result again (the first one was lost).
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._items: collections.deque[EvalRequest] = collections.deque()
        self._open: set[tuple[int, int]] = set()

    def put(self, request: EvalRequest) -> bool:
        """Queue `request`; False (and nothing queued) if it is queued or in progress."""
        key = request.key
        with self._cond:
            if key in self._open:
                return False
            self._open.add(key)
            self._items.append(request)
            self._cond.notify_all()
        return True

    def get(self, timeout_s: float) -> EvalRequest | None:
        """The oldest request, waiting up to `timeout_s`; None if none came. Call `done` with
        it when its result is published."""
        with self._cond:
            if not self._items:
                self._cond.wait(timeout_s)
            return self._items.popleft() if self._items else None

    def done(self, request: EvalRequest) -> None:
        with self._cond:
            self._open.discard(request.key)

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)


class EvaluatorService:
    """The evaluator's loop; `run()` returns when `runtime.stop` is set."""

    def __init__(self, *, runtime: ServiceRuntime, parts: ActorBuilder) -> None:
        self.runtime = runtime
        self.settings = parts.shell
        self.spec = self.settings.spec
        self.policy = parts.evaluator_policy()
        self._parts = parts
        self.worker = parts.evaluator_env()
        self.episodes_run = 0
        """Episodes drawn from the worker's goal stream since its seed (run or skipped)."""
        self.requests = EvalQueue()
        self.evaluations = 0
        self.weights_rejected = 0
        self.last_success_rate: float | None = None
        self._warn = WarnOncePerMinute(log)
        self._decoder = parts.decoder()
        keys = runtime.keys
        self._results: Publisher = runtime.transport.publisher(keys.eval_result, block=True)
        self.published: collections.OrderedDict[tuple[int, int], pb.EvalResult] = (
            collections.OrderedDict())
        """The newest results by (epoch, weights version), to answer a repeated request."""
        runtime.transport.subscribe(keys.weights, self._on_weights, latest=True, capacity=64)
        runtime.transport.subscribe(keys.eval_request, self._on_weights, capacity=16)

    def _on_weights(self, key: str, raw: bytes) -> None:
        """Subscription thread: keep eval requests, skip the rest; quick (no evaluation here)."""
        try:
            msg = self._decoder.parse(raw)
            if not msg.evaluate:
                return
            if msg.epoch > self.settings.epochs:
                # Its goals lie (epoch - 1) x eval_episodes episodes down the stream: a request
                # past the run's last epoch, which no learner of this run sends, would have
                # the evaluator reset its env that often (up to 2^64) before answering.
                raise InvalidMessage(Reason.BAD_VALUE, f"an evaluation of epoch {msg.epoch}, past "
                                     f"the run's {self.settings.epochs} epochs")
            request = EvalRequest(epoch=int(msg.epoch), weights=self._decoder.decode(msg))
        except InvalidMessage as exc:
            self.weights_rejected += 1
            self._warn.warn(f"weights:{exc.reason}",
                            f"ignored a Weights message on {key}: {exc}; no evaluation for it")
            return
        if self.requests.put(request):
            log.info("evaluation of epoch %d (weights version %d) queued (%d waiting)",
                     request.epoch, request.weights.version, len(self.requests))

    def _act(self, o: np.ndarray, g: np.ndarray) -> np.ndarray:
        return self.policy.act(o, g, explore=False)

    def evaluate(self, request: EvalRequest) -> pb.EvalResult | None:
        """Run the test episodes of one request; None if stopped before the last one."""
        self.policy.load(request.weights)
        n = self.settings.eval_episodes
        self._goals_of(request.epoch)
        successes, distances = 0, []
        for _ in range(n):
            if self.runtime.stop.is_set():
                return None
            episode = self.worker.run_episode(self._act)
            self.episodes_run += 1
            successes += int(episode.success)
            distances.append(float(goal_distance(episode.final_ag, episode.desired_goal)))
        return pb.EvalResult(
            schema_version=SCHEMA_VERSION,
            epoch=request.epoch,
            weights_version=request.weights.version,
            episodes=n,
            success_rate=successes / n,
            mean_final_distance=float(np.mean(distances)),
        )

    def _goals_of(self, epoch: int) -> None:
        """Put the goal stream where epoch `epoch`'s goals begin: after (epoch - 1) x
        eval_episodes episodes from the seed, the goals an unbroken run's evaluator tests that
        epoch on and `hercs eval` reproduces. A restarted evaluator (a resumed run) skips to
        them rather than testing epoch 31 on epoch 1's goals; an earlier epoch than the
        stream's place (asked again after a restart of the learner) starts a new stream."""
        start = (max(epoch, 1) - 1) * self.settings.eval_episodes
        if self.episodes_run > start:
            self.worker.close()
            self.worker, self.episodes_run = self._parts.evaluator_env(), 0
        if self.episodes_run < start:
            self.worker.skip(start - self.episodes_run)
            self.episodes_run = start

    def _publish(self, result: pb.EvalResult) -> None:
        deadline = time.monotonic() + SUBSCRIBER_WAIT_S
        while not self._results.wait_for_subscribers(_POLL_S):
            if self.runtime.stop.is_set():
                return
            if time.monotonic() >= deadline:
                log.warning("no subscriber on %s after %.0f s; publishing the result of epoch "
                            "%d anyway (it may be lost)", self._results.key, SUBSCRIBER_WAIT_S,
                            result.epoch)
                break
        self._results.put(result.SerializeToString())

    def run(self) -> int:
        stop = self.runtime.stop
        log.info("evaluator %s: run %r, task %s (%s), %d episodes per evaluation",
                 self.runtime.ident, self.settings.run, self.spec.name, self.spec.env_id,
                 self.settings.eval_episodes)
        self.publish_metrics(eval_s=0.0)
        while not stop.is_set():
            request = self.requests.get(_POLL_S)
            if request is None:
                continue
            cached = self.published.get(request.key)
            if cached is not None:
                log.info("epoch %d (weights version %d) asked for again: publishing its result "
                         "again", request.epoch, request.weights.version)
                self._publish(cached)
                self.requests.done(request)
                continue
            start = time.monotonic()
            result = self.evaluate(request)
            if result is None:
                break
            self._publish(result)
            self.requests.done(request)
            self.published[request.key] = result
            while len(self.published) > RESULTS_KEPT:
                self.published.popitem(last=False)
            self.evaluations += 1
            self.last_success_rate = result.success_rate
            elapsed = time.monotonic() - start
            log.info("epoch %d (weights version %d): success %.3f, final distance %.3f, "
                     "%.1f s", result.epoch, result.weights_version, result.success_rate,
                     result.mean_final_distance, elapsed)
            self.publish_metrics(eval_s=elapsed)
        return 0

    def publish_metrics(self, *, eval_s: float) -> None:
        values = {
            "evaluations": self.evaluations,
            "eval_s": eval_s,
            "queued": len(self.requests),
            "policy_version": self.policy.version,
            "weights_rejected": self.weights_rejected,
        }
        if self.last_success_rate is not None:
            values["success_rate"] = self.last_success_rate
        try:
            self.runtime.publish_metrics(values)
        except TransportError as exc:  # metrics are best effort
            self._warn.warn("metrics", f"could not publish metrics: {exc}")


def run(config: HercsConfig, *, ident: str | None = None) -> int:
    """`hercs evaluator`: evaluate every epoch-end policy until SIGTERM/SIGINT."""
    return service_main(role="evaluator", config=config, ident=ident, body=_work)


def _work(runtime: ServiceRuntime) -> int:
    service = EvaluatorService(runtime=runtime, parts=ActorBuilder(runtime.config))
    try:
        return service.run()
    finally:
        service.worker.close()
