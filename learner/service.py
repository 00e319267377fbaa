"""`hercs learner`: the DDPG learner process, a thin shell around `LearnerLoop`.

Threads:
- a prefetcher keeps the next cycles' batches coming: it sends `SampleRequest`s on
  `replay/sample` (the replay's rate limiter may hold them: that is the backpressure) and
  queues decoded batches, so the update loop rarely waits on the network;
- Zenoh subscription threads (hercs.transport) hand `EvalResult`s and `ReplayStatus` to
  thread-safe holders;
- the main thread runs cycles: updates, target update, weights broadcast (latest kept for
  late joiners), and at each epoch end the evaluation flag, a checkpoint and, when the
  evaluator answers, a `metrics.csv` row and a `Metrics` put for the launcher.
It exits 0 after the last epoch's evaluation is recorded.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hercs.codec import msg_to_minibatch, msg_to_stats, weights_to_msg
from hercs.config import HercsConfig
from hercs.errors import InvalidMessage
from hercs.service import ServiceRuntime, WarnOncePerMinute, service_main
from hercs.transport import RemoteError, TransportError, TransportTimeout
from hercs.validation import parse_message
from learner.ddpg import DDPGLearner
from learner.loop import LearnerLoop, MetricsCsv, SampleBatch
from proto import SCHEMA_VERSION
from proto import hercs_pb2 as pb

log = logging.getLogger("hercs.learner")

PREFETCH_DEPTH = 2
EVAL_WAIT_S = 600.0
MAX_BATCH_BYTES = 1 << 30


def decode_batch(raw: bytes) -> SampleBatch:
    msg = parse_message(raw, pb.Batch, max_bytes=MAX_BATCH_BYTES)
    return SampleBatch(
        minibatches=[msg_to_minibatch(mb, where=f"Batch.minibatches[{i}]")
                     for i, mb in enumerate(msg.minibatches)],
        o_stats=msg_to_stats(msg.o_stats, where="Batch.o_stats"),
        g_stats=msg_to_stats(msg.g_stats, where="Batch.g_stats"),
        cluster_model_version=int(msg.cluster_model_version),
        cluster_draws=np.asarray(msg.cluster_draws, np.int64),
        inserts=int(msg.inserts), env_steps=int(msg.env_steps), policy_lag=float(msg.policy_lag),
    )


class Prefetcher:
    """Requests batches ahead of the update loop on its own thread."""

    def __init__(self, *, runtime: ServiceRuntime, config: HercsConfig,
                 version: Callable[[], int]) -> None:
        self.runtime = runtime
        self.config = config
        self.version = version
        self.batches: queue.Queue[SampleBatch] = queue.Queue(maxsize=PREFETCH_DEPTH)
        self.warn = WarnOncePerMinute(log)
        self._request_id = 0
        self.waiting_s = 0.0
        self._thread = threading.Thread(target=self._run, name="prefetch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        stop = self.runtime.stop
        while not stop.is_set():
            self._request_id += 1
            request = pb.SampleRequest(
                schema_version=SCHEMA_VERSION, run=self.config.run.name,
                learner_id=self.runtime.ident, request_id=self._request_id,
                num_minibatches=self.config.training.minibatches_per_cycle,
                batch_size=self.config.ddpg.batch_size, weights_version=self.version())
            try:
                raw = self.runtime.transport.request(
                    self.runtime.keys.sample, request.SerializeToString(),
                    timeout_s=self.config.replay.sample_timeout_s)
                batch = decode_batch(raw)
            except (TransportTimeout, RemoteError, TransportError, InvalidMessage) as exc:
                if stop.is_set():
                    return
                self.warn.warn(type(exc).__name__, f"sample request failed ({exc}); retrying")
                stop.wait(0.5)
                continue
            while not stop.is_set():
                try:
                    self.batches.put(batch, timeout=0.5)
                    break
                except queue.Full:
                    continue

    def get(self) -> SampleBatch | None:
        """The next batch, or None once the service is stopping. Time spent waiting for one
        adds to `waiting_s`: the update loop idles then, so it is what prefetch failed to hide."""
        try:
            return self.batches.get_nowait()
        except queue.Empty:
            pass
        started = time.monotonic()
        try:
            while not self.runtime.stop.is_set():
                try:
                    return self.batches.get(timeout=0.5)
                except queue.Empty:
                    continue
            return None
        finally:
            self.waiting_s += time.monotonic() - started


class Latest:
    """The newest value of a stream, thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.value: Any = None

    def set(self, value: Any) -> None:
        with self._lock:
            self.value = value

    def get(self) -> Any:
        with self._lock:
            return self.value


def _status_dict(msg: pb.ReplayStatus) -> dict[str, Any]:
    return {"size_transitions": msg.size_transitions, "size_episodes": msg.size_episodes,
            "cluster_sizes": list(msg.cluster_sizes), "rejects": dict(msg.rejects),
            "rate_limiter": msg.rate_limiter}


class LearnerService:
    def __init__(self, *, config: HercsConfig, runtime: ServiceRuntime, run_dir: Path) -> None:
        self.config = config
        self.runtime = runtime
        self.run_dir = run_dir
        self.learner = DDPGLearner(spec=config.task.spec, config=config.ddpg,
                                   seed=config.run.seed)
        self.loop = LearnerLoop(config=config, learner=self.learner)
        self.metrics = MetricsCsv(run_dir / "metrics.csv")
        self.batch_wait_s: dict[int, float] = {}  # epoch -> seconds the updates waited
        (run_dir / "checkpoints").mkdir(exist_ok=True)
        self.evals: queue.Queue[pb.EvalResult] = queue.Queue()
        self.status = Latest()
        self.warn = WarnOncePerMinute(log)
        keys, transport = runtime.keys, runtime.transport
        self.weights_pub = transport.publisher(keys.weights, latest=True, block=True)
        transport.subscribe(keys.eval_result, self._on_eval)
        transport.subscribe(keys.status, self._on_status, drop_oldest=True, capacity=4)

    def _on_eval(self, key: str, payload: bytes) -> None:
        try:
            self.evals.put(parse_message(payload, pb.EvalResult, max_bytes=1 << 20))
        except InvalidMessage as exc:
            self.warn.warn("eval", f"ignored an EvalResult: {exc}")

    def _on_status(self, key: str, payload: bytes) -> None:
        try:
            self.status.set(_status_dict(parse_message(payload, pb.ReplayStatus,
                                                       max_bytes=1 << 20)))
        except InvalidMessage as exc:
            self.warn.warn("status", f"ignored a ReplayStatus: {exc}")

    def publish_weights(self, *, evaluate: bool, epoch: int) -> None:
        weights = self.learner.policy_weights(self.loop.version)
        msg = weights_to_msg(version=weights.version, actor_params=weights.actor,
                             o_stats=weights.o_stats, g_stats=weights.g_stats, epoch=epoch,
                             evaluate=evaluate)
        self.weights_pub.put(msg.SerializeToString())

    def checkpoint(self) -> None:
        path = self.run_dir / "checkpoints" / "learner.pt"
        tmp = path.with_suffix(".pt.tmp")
        torch.save({"learner": self.learner.state_dict(), "version": self.loop.version,
                    "epoch": self.loop.epoch, "cycle": self.loop.cycle}, tmp)
        os.replace(tmp, path)

    def record_evals(self, *, block: bool) -> None:
        """Write the rows of evaluated epochs; with block, wait for every pending epoch."""
        while self.loop.pending:
            try:
                result = self.evals.get(timeout=EVAL_WAIT_S) if block else self.evals.get_nowait()
            except queue.Empty:
                if block:
                    log.error("no evaluation arrived for epoch(s) %s within %.0f s",
                              sorted(self.loop.pending), EVAL_WAIT_S)
                return
            row = self.loop.record_eval(epoch=int(result.epoch),
                                        success_rate=float(result.success_rate),
                                        mean_final_distance=float(result.mean_final_distance),
                                        replay_status=self.status.get())
            if row is None:
                continue
            row["batch_wait_s"] = round(self.batch_wait_s.pop(int(row["epoch"]), 0.0), 3)
            self.metrics.write(row)
            values = {k: v for k, v in row.items() if isinstance(v, int | float)}
            values["epochs"] = self.config.training.epochs
            self.runtime.publish_metrics(values, step=int(row["epoch"]))
            log.info("epoch %d: success %.2f, env steps %d, %.0f updates/s", row["epoch"],
                     row["success_rate"], row["env_steps"], row["updates_per_s"])

    def run(self) -> int:
        stop = self.runtime.stop
        self.publish_weights(evaluate=False, epoch=0)
        prefetcher = Prefetcher(runtime=self.runtime, config=self.config,
                                version=lambda: self.loop.version)
        waited_before = 0.0
        while not self.loop.done and not stop.is_set():
            batch = prefetcher.get()
            if batch is None:
                break
            result = self.loop.step(batch)
            self.publish_weights(evaluate=result.epoch_ended is not None,
                                 epoch=result.epoch_ended or self.loop.epoch)
            if result.epoch_ended is not None:
                self.batch_wait_s[result.epoch_ended] = prefetcher.waiting_s - waited_before
                waited_before = prefetcher.waiting_s
                self.checkpoint()
            self.record_evals(block=False)
        if stop.is_set():
            return 0
        self.record_evals(block=True)
        return 0 if not self.loop.pending else 1

    def close(self) -> None:
        self.metrics.close()


def run(config: HercsConfig, *, ident: str | None = None) -> int:
    """`hercs learner`: train for `training.epochs` epochs, then exit 0."""
    torch.set_num_threads(1)
    return service_main(role="learner", config=config, ident=ident or "learner", body=_work)


def _work(runtime: ServiceRuntime) -> int:
    config = runtime.config
    run_dir = Path(config.run.run_dir) / config.run.name
    run_dir.mkdir(parents=True, exist_ok=True)
    service = LearnerService(config=config, runtime=runtime, run_dir=run_dir)
    try:
        return service.run()
    finally:
        runtime.stop.set()
        service.close()
