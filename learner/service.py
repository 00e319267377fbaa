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
import math
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hercs.codec import msg_to_stats, weights_to_msg
from hercs.config import HercsConfig
from hercs.errors import InvalidMessage
from hercs.normalizer import Normalizer
from hercs.rundir import BEST, epoch_file
from hercs.service import ServiceRuntime, service_main
from hercs.tasks import TaskSpec
from hercs.transport import RemoteError, TransportError, TransportTimeout
from hercs.validation import (
    MAX_INT64,
    RejectReason,
    decode_minibatch,
    parse_message,
    validate_eval_result,
)
from hercs.warn_once import WarnOncePerMinute
from learner.checkpoint import (
    load_checkpoint,
    load_policy_file,
    save_checkpoint,
    save_policy,
)
from learner.ddpg import DDPGLearner
from learner.loop import (
    LearnerLoop,
    MetricsCsv,
    SampleBatch,
    recorded_epochs,
    truncate_metrics,
)
from learner.tensorboard import TensorBoardScalars
from proto import SCHEMA_VERSION
from proto import hercs_pb2 as pb

log = logging.getLogger("hercs.learner")

_POLL_S = 0.5
MAX_BATCH_BYTES = 1 << 30


def decode_batch(raw: bytes, *, spec: TaskSpec, k: int, batch_size: int,
                 num_minibatches: int) -> SampleBatch:
    """A `Batch` reply checked before any update sees it: the minibatches asked for, each of
    the task's shapes, float32 and finite (`decode_minibatch`), normaliser statistics that a
    normaliser of the task's sizes accepts, and `k` cluster draws (or none). Raises
    `InvalidMessage` naming what is wrong."""
    msg = parse_message(raw, pb.Batch, max_bytes=MAX_BATCH_BYTES)
    if len(msg.minibatches) != num_minibatches:
        raise InvalidMessage(RejectReason.BAD_LENGTH,
                             f"Batch: {len(msg.minibatches)} minibatches, asked for "
                             f"{num_minibatches}")
    minibatches = [decode_minibatch(mb, spec, batch_size=batch_size,
                                    where=f"Batch.minibatches[{i}]")
                   for i, mb in enumerate(msg.minibatches)]
    o_stats = msg_to_stats(msg.o_stats, where="Batch.o_stats")
    g_stats = msg_to_stats(msg.g_stats, where="Batch.g_stats")
    for stats, size, where in ((o_stats, spec.obs_dim, "Batch.o_stats"),
                               (g_stats, spec.goal_dim, "Batch.g_stats")):
        try:
            Normalizer(size).load_state_dict(stats)
        except ValueError as exc:
            raise InvalidMessage(RejectReason.BAD_VALUE, f"{where}: {exc}") from None
    if len(msg.cluster_draws) not in (0, k):
        raise InvalidMessage(RejectReason.BAD_LENGTH,
                             f"Batch.cluster_draws: {len(msg.cluster_draws)} values, expected "
                             f"{k} (cluster.k) or none")
    if msg.sampled_moved > msg.sampled_transitions:
        raise InvalidMessage(RejectReason.BAD_VALUE,
                             f"Batch.sampled_moved {msg.sampled_moved} exceeds "
                             f"Batch.sampled_transitions {msg.sampled_transitions}")
    if not 0.0 <= msg.buffer_moved_share <= 1.0:
        raise InvalidMessage(RejectReason.BAD_VALUE,
                             f"Batch.buffer_moved_share {msg.buffer_moved_share!r} is not a "
                             "share in [0, 1]")
    if any(d > MAX_INT64 for d in msg.cluster_draws):  # they are summed in an int64 array
        raise InvalidMessage(RejectReason.BAD_VALUE,
                             f"Batch.cluster_draws: {list(msg.cluster_draws)} holds a value "
                             f"above {MAX_INT64}")
    return SampleBatch(
        minibatches=minibatches, o_stats=o_stats, g_stats=g_stats,
        cluster_model_version=int(msg.cluster_model_version),
        cluster_draws=np.asarray(msg.cluster_draws, np.int64),
        inserts=int(msg.inserts), env_steps=int(msg.env_steps),
        policy_lag=float(msg.policy_lag) if math.isfinite(msg.policy_lag) else 0.0,
        policy_lag_request=(float(msg.policy_lag_request) if math.isfinite(msg.policy_lag_request)
                            else 0.0),
        policy_lags=np.asarray(msg.policy_lags, np.int64),
        sampled_moved=int(msg.sampled_moved), sampled_transitions=int(msg.sampled_transitions),
        buffer_moved_share=float(msg.buffer_moved_share),
    )


class Prefetcher:
    """Requests batches ahead of the update loop on its own thread.

    At most `learner.prefetch_depth` batches are sampled and not yet taken by the loop: each
    request takes a credit, each `get` gives one back before it waits, so with depth 0 a
    batch is asked for only when the loop wants it. Every batch sampled ahead lets the rate
    limiter admit a cycle of episodes more before their weights exist: one cycle of policy lag
    per batch of depth (docs/DESIGN.md §9.1).

    In the lockstep schedule it asks for nothing ahead: cycle c's request (weights_version c)
    is sent once the loop has reached version c (`cycle_done` wakes it), and the replay holds
    it until cycle c's episodes are stored."""

    def __init__(self, *, runtime: ServiceRuntime, config: HercsConfig,
                 version: Callable[[], int]) -> None:
        self.runtime = runtime
        self.config = config
        self.version = version
        self.lockstep = config.training.schedule == "lockstep"
        self._advanced = threading.Condition()
        self.batches: queue.Queue[SampleBatch] = queue.Queue()  # bounded by the credits
        self._credits = threading.Semaphore(config.learner.prefetch_depth)
        self.warn = WarnOncePerMinute(log)
        self._request_id = 0
        self.waiting_s = 0.0
        self.bad_batches: Counter[str] = Counter()
        """Batch replies skipped because they failed validation, by reason."""
        self._thread = runtime.start_thread(self._run, name="prefetch")

    def cycle_done(self) -> None:
        """The loop finished a cycle and broadcast its weights (lockstep's cue)."""
        with self._advanced:
            self._advanced.notify_all()

    def _wait_for_version(self, wanted: int) -> bool:
        """Lockstep: wait until the loop is at `wanted`; False if stopped first."""
        stop = self.runtime.stop
        with self._advanced:
            while self.version() < wanted:
                if stop.is_set():
                    return False
                self._advanced.wait(_POLL_S)
        return not stop.is_set()

    def _run(self) -> None:
        stop = self.runtime.stop
        wanted = self.version()  # lockstep: the cycle the next request is for
        while not stop.is_set():
            if not self._credits.acquire(timeout=_POLL_S):
                continue
            if self.lockstep and not self._wait_for_version(wanted):
                return
            if not self._fetch(wanted):
                self._credits.release()  # nothing was sampled with it
                continue
            wanted += 1

    def _fetch(self, wanted: int) -> bool:
        """One request for cycle `wanted`; True once its batch is queued, False if it failed
        (counted and warned; the caller asks again) or the service is stopping."""
        stop = self.runtime.stop
        self._request_id += 1
        request = pb.SampleRequest(
            schema_version=SCHEMA_VERSION, run=self.config.run.name,
            learner_id=self.runtime.ident, request_id=self._request_id,
            num_minibatches=self.config.training.minibatches_per_cycle,
            batch_size=self.config.ddpg.batch_size,
            weights_version=wanted if self.lockstep else self.version())
        try:
            raw = self.runtime.transport.request(
                self.runtime.keys.sample, request.SerializeToString(),
                timeout_s=self.config.replay.sample_timeout_s)
            batch = decode_batch(raw, spec=self.config.task.spec, k=self.config.cluster.k,
                                 batch_size=self.config.ddpg.batch_size,
                                 num_minibatches=self.config.training.minibatches_per_cycle)
        except InvalidMessage as exc:  # a reply no update may see: counted, skipped
            self.bad_batches[exc.reason] += 1
            self.warn.warn(f"bad:{exc.reason}", f"skipped a bad Batch ({exc}); asking again")
            return False
        except (TransportTimeout, RemoteError, TransportError) as exc:
            if not stop.is_set():
                self.warn.warn(type(exc).__name__, f"sample request failed ({exc}); retrying")
                stop.wait(0.5)
            return False
        self.batches.put(batch)
        return True

    def get(self) -> SampleBatch | None:
        """The next batch, or None once the service is stopping. Time spent waiting for one
        adds to `waiting_s`: the update loop idles then, so it is what prefetch failed to hide."""
        self._credits.release()  # room for the batch after the ones already sampled
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
    """The learner's process side around `LearnerLoop`.

    Resume: if `checkpoints/learner.pt` exists the learner continues from it (the end of the
    last checkpointed epoch): DDPG state, counters, weights version, the run's wall time and
    the epochs waiting for evaluation; `metrics.csv` keeps its rows up to that epoch (rows of
    later epochs, possible only after a failed checkpoint write, are dropped: those epochs are
    trained again) and a pending epoch that already has its row is not evaluated again.

    Evaluation requests: each epoch end broadcasts the weights with `evaluate=True`. An epoch
    whose `EvalResult` has not come after `training.eval_resend_s` (lost while the router
    restarted, an evaluator that died, or a resume) is asked for again on `eval/request` with
    the same weights; the evaluator answers from its cache or evaluates. After
    `training.eval_wait_s` in all the
    run ends with status 1. Every wait watches the stop event.
    """

    def __init__(self, *, config: HercsConfig, runtime: ServiceRuntime, run_dir: Path) -> None:
        self.config = config
        self.runtime = runtime
        self.run_dir = run_dir
        self.checkpoints = run_dir / "checkpoints"
        self.learner = DDPGLearner(spec=config.task.spec, config=config.ddpg,
                                   seed=config.run.seed, device=config.learner.device,
                                   precision=config.learner.precision)
        log.info("learner on %s (learner.device=%s), %s", self.learner.device,
                 config.learner.device, config.learner.precision)
        self.loop = LearnerLoop(config=config, learner=self.learner)
        self.batch_wait_s: dict[int, float] = {}  # epoch -> seconds the updates waited
        self.eval_requests: dict[int, bytes] = {}  # pending epoch -> its Weights message
        self._eval_asked: dict[int, float] = {}  # pending epoch -> when it was last asked for
        self.resumed_from: int | None = None
        self.prefetcher_bad: Counter[str] = Counter()
        self._resume()
        best = load_policy_file(self.checkpoints / BEST)
        self.best_success: float | None = None if best is None else float(best["success_rate"])
        self.metrics = MetricsCsv(run_dir / "metrics.csv")
        self.tensorboard = (TensorBoardScalars(run_dir / "tensorboard",
                                               after_epoch=self.loop.epoch)
                            if config.run.tensorboard else None)
        self.evals: queue.Queue[pb.EvalResult] = queue.Queue()
        self.status = Latest()
        self.warn = WarnOncePerMinute(log)
        keys, transport = runtime.keys, runtime.transport
        self.weights_pub = transport.publisher(keys.weights, latest=True, block=True)
        self.eval_request_pub = transport.publisher(keys.eval_request, block=True)
        self.progress_pub = transport.publisher(keys.progress, latest=True, block=True)
        transport.subscribe(keys.eval_result, self._on_eval)
        transport.subscribe(keys.status, self._on_status, drop_oldest=True, capacity=4)

    # -- resume ------------------------------------------------------------------------------
    def _resume(self) -> None:
        state = load_checkpoint(self.checkpoints)
        metrics_path = self.run_dir / "metrics.csv"
        if state is None:
            dropped = truncate_metrics(metrics_path, through_epoch=0)
            if dropped:
                log.warning("no checkpoint: metrics.csv rows of epochs %s dropped (retrained)",
                            dropped)
            return
        self.learner.load_state_dict(state["learner"])
        self.loop.load_state_dict(state["loop"])
        torch.set_rng_state(state["torch_rng"])
        epoch = self.loop.epoch
        dropped = truncate_metrics(metrics_path, through_epoch=epoch)
        recorded = set(recorded_epochs(metrics_path))
        for pending in [e for e in self.loop.pending if e in recorded]:
            del self.loop.pending[pending]  # its row was written after the checkpoint
        self.eval_requests = {int(e): bytes(raw) for e, raw in state["eval_requests"].items()
                              if int(e) in self.loop.pending}
        self._eval_asked = dict.fromkeys(self.eval_requests, -math.inf)  # ask again at once
        self.resumed_from = epoch
        log.info("resumed from the checkpoint of epoch %d (weights version %d, %d updates)%s%s",
                 epoch, self.loop.version, self.learner.updates,
                 f"; metrics rows of epochs {dropped} dropped (retrained)" if dropped else "",
                 f"; epochs {sorted(self.loop.pending)} still to be evaluated"
                 if self.loop.pending else "")

    def checkpoint(self) -> None:
        save_checkpoint(self.checkpoints, {
            "learner": self.learner.state_dict(), "loop": self.loop.state_dict(),
            "torch_rng": torch.get_rng_state(), "eval_requests": dict(self.eval_requests),
            "config": self.config.to_dict(),
        })

    # -- subscriptions -----------------------------------------------------------------------
    def _on_eval(self, key: str, payload: bytes) -> None:
        try:
            msg = parse_message(payload, pb.EvalResult, max_bytes=1 << 20)
            rejection = validate_eval_result(msg)
            if rejection is not None:
                raise rejection.error()
        except InvalidMessage as exc:
            self.warn.warn("eval", f"ignored an EvalResult: {exc}")
            return
        self.evals.put(msg)

    def _on_status(self, key: str, payload: bytes) -> None:
        try:
            self.status.set(_status_dict(parse_message(payload, pb.ReplayStatus,
                                                       max_bytes=1 << 20)))
        except InvalidMessage as exc:
            self.warn.warn("status", f"ignored a ReplayStatus: {exc}")

    # -- broadcasts --------------------------------------------------------------------------
    def publish_weights(self, *, evaluate: bool, epoch: int) -> None:
        weights = self.learner.policy_weights(self.loop.version)
        raw = weights_to_msg(version=weights.version, actor_params=weights.actor,
                             o_stats=weights.o_stats, g_stats=weights.g_stats, epoch=epoch,
                             evaluate=evaluate).SerializeToString()
        if evaluate:
            self.eval_requests[epoch] = raw
            self._eval_asked[epoch] = time.monotonic()
        self.weights_pub.put(raw)

    def publish_progress(self, *, finished: bool = False) -> None:
        recorded = self.loop.epoch - len(self.loop.pending)
        self.progress_pub.put(pb.RunProgress(
            schema_version=SCHEMA_VERSION, epoch=max(recorded, 0),
            epochs=self.config.training.epochs, finished=finished).SerializeToString())

    def _ask_again(self) -> None:
        """Ask once more for the evaluations overdue by `training.eval_resend_s`."""
        now = time.monotonic()
        for epoch in sorted(self.loop.pending):
            raw = self.eval_requests.get(epoch)
            overdue = now - self._eval_asked.get(epoch, now)
            if raw is not None and overdue >= self.config.training.eval_resend_s:
                log.info("no evaluation of epoch %d yet: asking again", epoch)
                self.eval_request_pub.put(raw)
                self._eval_asked[epoch] = now

    # -- evaluation results ------------------------------------------------------------------
    def record_evals(self, *, block: bool) -> None:
        """Write the rows of evaluated epochs; with block, wait (watching the stop event, asking
        again for overdue evaluations) until every pending epoch is recorded or
        `training.eval_wait_s` has passed."""
        stop = self.runtime.stop
        wait_s = self.config.training.eval_wait_s
        deadline = time.monotonic() + wait_s
        while self.loop.pending and not stop.is_set():
            self._ask_again()
            try:
                result = (self.evals.get(timeout=_POLL_S) if block
                          else self.evals.get_nowait())
            except queue.Empty:
                if not block:
                    return
                if time.monotonic() >= deadline:
                    log.error("no evaluation arrived for epoch(s) %s within %.0f s",
                              sorted(self.loop.pending), wait_s)
                    return
                continue
            self._record(result)

    def _record(self, result: pb.EvalResult) -> None:
        snapshot = self.loop.pending.get(int(result.epoch))
        if snapshot is not None and snapshot.version != result.weights_version:
            self.warn.warn("eval:version", f"ignored an EvalResult of epoch {result.epoch}: it "
                           f"evaluated weights version {result.weights_version}, the epoch "
                           f"ended at version {snapshot.version}")
            return
        row = self.loop.record_eval(epoch=int(result.epoch),
                                    success_rate=float(result.success_rate),
                                    mean_final_distance=float(result.mean_final_distance),
                                    replay_status=self.status.get())
        if row is None:
            return  # an epoch not pending: a repeated or stale answer
        epoch = int(row["epoch"])
        raw = self.eval_requests.pop(epoch, None)
        self._eval_asked.pop(epoch, None)
        if raw is not None:
            self._keep_policy(epoch, raw, float(row["success_rate"]))
        row["batch_wait_s"] = round(self.batch_wait_s.pop(epoch, 0.0), 3)
        row["bad_batches"] = sum(self.prefetcher_bad.values())
        self.metrics.write(row)
        if self.tensorboard is not None:
            self.tensorboard.write(row)
        values = {k: v for k, v in row.items() if isinstance(v, int | float)}
        values["epochs"] = self.config.training.epochs
        self.runtime.publish_metrics(values, step=epoch)
        self.publish_progress()
        log.info("epoch %d: success %.2f, env steps %d, %.0f updates/s", epoch,
                 row["success_rate"], row["env_steps"], row["updates_per_s"])

    def _keep_policy(self, epoch: int, weights: bytes, success_rate: float) -> None:
        """`best.pt` when this epoch beats every earlier one; `epoch-NNNN.pt` every
        `training.checkpoint_every` epochs."""
        every = self.config.training.checkpoint_every
        names = [epoch_file(epoch)] if every and epoch % every == 0 else []
        if self.best_success is None or success_rate > self.best_success:
            names.append(BEST)
        for name in names:
            kept = save_policy(self.checkpoints, name, weights=weights, epoch=epoch,
                               success_rate=success_rate, config=self.config.to_dict())
            if kept and name == BEST:
                self.best_success = success_rate

    # -- the loop ----------------------------------------------------------------------------
    def run(self) -> int:
        stop = self.runtime.stop
        if self.loop.done and not self.loop.pending:
            log.info("this run's %d epochs are already done", self.config.training.epochs)
            self.publish_progress(finished=True)
            return 0
        self.publish_weights(evaluate=False, epoch=self.loop.epoch)
        self.publish_progress()
        prefetcher = Prefetcher(runtime=self.runtime, config=self.config,
                                version=lambda: self.loop.version)
        self.prefetcher_bad = prefetcher.bad_batches
        waited_before = 0.0
        while not self.loop.done and not stop.is_set():
            batch = prefetcher.get()
            if batch is None:
                break
            result = self.loop.step(batch)
            self.publish_weights(evaluate=result.epoch_ended is not None,
                                 epoch=result.epoch_ended or self.loop.epoch)
            prefetcher.cycle_done()
            if result.epoch_ended is not None:
                self.batch_wait_s[result.epoch_ended] = prefetcher.waiting_s - waited_before
                waited_before = prefetcher.waiting_s
                self.checkpoint()
            self.record_evals(block=False)
        if stop.is_set():
            return 0
        self.record_evals(block=True)
        if stop.is_set():
            return 0
        if self.loop.pending:
            return 1
        self.publish_progress(finished=True)
        return 0

    def close(self) -> None:
        self.metrics.close()
        if self.tensorboard is not None:
            self.tensorboard.close()


def run(config: HercsConfig, *, ident: str | None = None) -> int:
    """`hercs learner`: train for `training.epochs` epochs, then exit 0."""
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
