"""`hercs learner`: the DDPG learner process, a thin shell around `LearnerLoop`.

The prefetcher thread (hercs.learner.prefetch) asks `replay/sample` for batches; a subscription
thread queues `EvalResult`s; the main thread runs cycles, broadcasts weights, checkpoints at each
epoch end and writes a `metrics.csv` row per evaluation. It exits 0 after the last epoch's
evaluation is recorded, and `EXIT_DIVERGED` (4) when a loss or weight stops being finite.
"""

from __future__ import annotations

import logging
import queue
import time
from collections import Counter
from pathlib import Path

from hercs.config import HercsConfig
from hercs.errors import Diverged, InvalidMessage
from hercs.learner.builder import LearnerBuilder
from hercs.learner.checkpoint import load_policy_file, save_policy
from hercs.learner.replay_status import Stopping
from hercs.learner.resume import resume_learner_state, save_learner_state
from hercs.net.service_shell import ServiceRuntime, service_main
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Disposition, Reason
from hercs.run.metrics import MetricsCsv
from hercs.run.rundir import LATEST, RunDir, run_dir_of
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.codec import weights_to_msg
from hercs.wire.validation import parse_message, validate_eval_result

log = logging.getLogger("hercs.learner")

_POLL_S = 0.5


class LearnerService:
    """The learner's process side around `LearnerLoop`.

    Resume: from `checkpoints/learner.pt` when it exists (hercs.learner.resume).

    Evaluation: each epoch end broadcasts the weights with `evaluate=True`; an overdue one is
    asked for again on `eval/request` (hercs.learner.evaluations.EvalRequests). After
    `training.eval_wait_s` in all the run ends with status 1. Every wait watches the stop
    event.
    """

    def __init__(self, *, parts: LearnerBuilder, runtime: ServiceRuntime,
                 run_dir: Path) -> None:
        self.parts = parts
        self.settings = parts.shell
        self.runtime = runtime
        self.run_dir = run_dir
        self.files = RunDir(run_dir)
        self.checkpoints = self.files.checkpoints
        self.learner = parts.learner()
        log.info("learner on %s (learner.device=%s), %s", self.learner.device,
                 self.settings.device_request, self.learner.precision)
        self.replay_status = parts.replay_status(runtime)
        self.loop = parts.loop(self.learner, replay_status=self.replay_status)
        self.batch_wait_s: dict[int, float] = {}  # epoch -> seconds the updates waited
        self.eval_requests = parts.eval_requests()
        self.prefetcher_bad: Counter[str] = Counter()
        self.resumed_from = resume_learner_state(
            self.checkpoints, self.files.metrics, learner=self.learner, loop=self.loop,
            eval_requests=self.eval_requests)
        self.checkpointed_epoch: int | None = self.resumed_from
        """The epoch of the newest checkpoint on disk (None: none yet)."""
        best = load_policy_file(self.files.checkpoint("best"))
        self.keeper = parts.keeper(best_success=None if best is None
                                   else float(best["success_rate"]))
        self.metrics = MetricsCsv(self.files.metrics)
        self.evals: queue.Queue[pb.EvalResult] = queue.Queue()
        self.warn = WarnOncePerMinute(log)
        keys, transport = runtime.keys, runtime.transport
        self.weights_pub = transport.publisher(keys.weights, latest=True, block=True)
        self.eval_request_pub = transport.publisher(keys.eval_request, block=True)
        self.progress_pub = transport.publisher(keys.progress, latest=True, block=True)
        transport.subscribe(keys.eval_result, self._on_eval)

    def checkpoint(self) -> None:
        try:
            saved = save_learner_state(self.checkpoints, learner=self.learner, loop=self.loop,
                                       eval_requests=self.eval_requests,
                                       config_record=self.settings.config_record)
        except Diverged as exc:
            raise Diverged(f"training diverged by the end of epoch {self.loop.epoch}: {exc}; "
                           f"{self.kept_checkpoint()}") from None
        if saved:
            self.checkpointed_epoch = self.loop.epoch

    def kept_checkpoint(self) -> str:
        """What a diverged learner leaves to continue from, and how."""
        if self.checkpointed_epoch is None:
            return ("no checkpoint was written before it; start a new run with other "
                    "settings (e.g. a lower ddpg.lr_actor or ddpg.lr_critic)")
        return (f"the last sound checkpoint, {self.checkpoints / LATEST} of epoch "
                f"{self.checkpointed_epoch}, is kept: `hercs up --resume {self.run_dir}` "
                "continues from it, with --set for what diverged (e.g. a lower ddpg.lr_actor "
                "or ddpg.lr_critic)")

    # -- subscriptions -----------------------------------------------------------------------
    def _on_eval(self, key: str, payload: bytes) -> None:
        try:
            msg = parse_message(payload, pb.EvalResult, max_bytes=1 << 20)
            validate_eval_result(msg)
        except InvalidMessage as exc:
            self.warn.warn("eval", f"ignored an EvalResult: {exc}")
            return
        self.evals.put(msg)

    # -- broadcasts --------------------------------------------------------------------------
    def publish_weights(self, *, evaluate: bool, epoch: int) -> None:
        weights = self.learner.policy_weights(self.loop.version)
        raw = weights_to_msg(version=weights.version, actor_params=weights.actor,
                             o_stats=weights.o_stats, g_stats=weights.g_stats, epoch=epoch,
                             evaluate=evaluate).SerializeToString()
        if evaluate:
            self.eval_requests.sent(epoch, raw)
        self.weights_pub.put(raw)

    def publish_progress(self, *, finished: bool = False, diverged: bool = False) -> None:
        """Where the run stands: epochs recorded, and the cycles and updates done (what
        `hercs up`'s live line shows within an epoch); `diverged`: the run's training stopped
        for good (a learner `hercs up` did not start says so: hercs.learner.stacked_shell)."""
        recorded = self.loop.epoch - len(self.loop.pending)
        self.progress_pub.put(pb.RunProgress(
            schema_version=SCHEMA_VERSION, epoch=max(recorded, 0),
            epochs=self.settings.epochs, finished=finished, diverged=diverged,
            cycle=self.loop.cycle,
            cycles_per_epoch=self.settings.cycles_per_epoch,
            updates=self.learner.updates).SerializeToString())

    def _ask_again(self) -> None:
        """Ask once more for the evaluations overdue by `training.eval_resend_s`."""
        for epoch, raw in self.eval_requests.overdue(self.loop.pending):
            log.info("no evaluation of epoch %d yet: asking again", epoch)
            self.eval_request_pub.put(raw)

    # -- evaluation results ------------------------------------------------------------------
    def record_evals(self, *, block: bool) -> None:
        """Write the rows of evaluated epochs; with block, wait (watching the stop event, asking
        again for overdue evaluations) until every pending epoch is recorded or
        `training.eval_wait_s` has passed."""
        stop = self.runtime.stop
        wait_s = self.settings.eval_wait_s
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
                                    mean_final_distance=float(result.mean_final_distance))
        if row is None:
            return  # an epoch not pending: a repeated or stale answer
        epoch = int(row["epoch"])
        raw = self.eval_requests.answered(epoch)
        if raw is not None:
            self._keep_policy(epoch, raw, float(row["success_rate"]))
        row["batch_wait_s"] = round(self.batch_wait_s.pop(epoch, 0.0), 3)
        row["bad_batches"] = sum(self.prefetcher_bad.values())
        self.metrics.write(row)
        values = {k: v for k, v in row.items() if isinstance(v, int | float)}
        values["epochs"] = self.settings.epochs
        values["bad_episodes"] = bad_episodes(str(row.get("rejects", "")))
        self.runtime.publish_metrics(values, step=epoch)
        self.publish_progress()
        log.info("epoch %d: success %.2f, env steps %d, %.0f updates/s", epoch,
                 row["success_rate"], row["env_steps"], row["updates_per_s"])

    def _keep_policy(self, epoch: int, weights: bytes, success_rate: float) -> None:
        for name in self.keeper.files_for(epoch, success_rate):
            if save_policy(self.checkpoints, name, weights=weights, epoch=epoch,
                           success_rate=success_rate,
                           config=self.settings.config_record):
                self.keeper.saved(name, success_rate)

    # -- the loop ----------------------------------------------------------------------------
    def run(self) -> int:
        stop = self.runtime.stop
        if self.loop.done and not self.loop.pending:
            log.info("this run's %d epochs are already done", self.settings.epochs)
            self.publish_progress(finished=True)
            return 0
        self.publish_weights(evaluate=False, epoch=self.loop.epoch)
        self.publish_progress()
        prefetcher = self.parts.prefetcher(self.runtime, version=lambda: self.loop.version,
                                           samples_kept=self.learner.updates)
        self.prefetcher_bad = prefetcher.bad_batches
        waited_before = 0.0
        while not self.loop.done and not stop.is_set():
            batch = prefetcher.get()
            if batch is None:
                break
            try:
                result = self.loop.step(batch)
            except Diverged as exc:  # nothing of this cycle is published or saved
                raise Diverged(f"{exc}; {self.kept_checkpoint()}") from None
            except Stopping:  # at an epoch's end, before its row or checkpoint: redone on resume
                return 0
            self.publish_weights(evaluate=result.epoch_ended is not None,
                                 epoch=result.epoch_ended or self.loop.epoch)
            prefetcher.cycle_done()
            if result.epoch_ended is not None:
                self.batch_wait_s[result.epoch_ended] = prefetcher.waiting_s - waited_before
                waited_before = prefetcher.waiting_s
                self.checkpoint()
            self.publish_progress()
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


def run(config: HercsConfig, *, ident: str | None = None) -> int:
    """`hercs learner`: train for `training.epochs` epochs, then exit 0."""
    return service_main(role="learner", config=config, ident=ident or "learner", body=_work)


def _work(runtime: ServiceRuntime) -> int:
    config = runtime.config
    run_dir = run_dir_of(config.run)
    run_dir.mkdir(parents=True, exist_ok=True)
    service = LearnerService(parts=LearnerBuilder(config), runtime=runtime, run_dir=run_dir)
    try:
        return service.run()
    finally:
        runtime.stop.set()
        service.close()


def bad_episodes(rejects: str) -> int:
    """Of a metrics row's `rejects` ("reason:count;…"), the inserts refused as bad input
    (a `Disposition.DROP` reason: malformed or implausible), not the stale ones an
    asynchronous run refuses all the time: what `hercs up`'s epoch line shows."""
    total = 0
    for item in filter(None, rejects.split(";")):
        reason, _, count = item.partition(":")
        if reason in BAD_INPUT and count.isdigit():
            total += int(count)
    return total


BAD_INPUT = frozenset(r.value for r in Reason if r.disposition is Disposition.DROP)
