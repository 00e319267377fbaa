"""The replay table: everything the replay service decides, with no transport (Reverb's
`Table` is the model). `ReplayTable` owns the `ReplayCore`, the rate limiter or lockstep gate,
the parked calls (hercs.replay_service.parked_calls), the log's group commit and the
`PolicyLagLedger`. Every public method takes the table's lock and waiters are called under it,
so they must only hand their answer over.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable

from hercs.config import HercsConfig
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.admission import admission_for
from hercs.replay_service.learner_follow import follow_learner
from hercs.replay_service.lockstep import LOCKSTEP_CLUSTER_WAIT_S
from hercs.replay_service.parked_calls import ParkedCalls, check_unstored, insert_key
from hercs.replay_service.policy_lag import PolicyLagLedger
from hercs.replay_service.replay_core import ReplayCore
from hercs.replay_service.table_calls import (
    ClustererSnapshot,
    EpisodeIdConflict,
    EpisodeLogSink,
    ParkedInsert,
    ParkedSample,
    SampleCall,
    SampleRefused,
    Stored,
    Waiter,
    start_segment,
)
from hercs.rl.cluster_model import ClusterModel
from hercs.wire.episode import EpisodeData
from hercs.wire.replay_state import ReplayState
from hercs.wire.served import ReplayCounters, ServedBatch

__all__ = ["LOCKSTEP_CLUSTER_WAIT_S", "ClustererSnapshot", "EpisodeLogSink", "ReplayTable",
           "SampleCall", "SampleRefused", "Stored", "Waiter"]  # calls and answers: table_calls

log = logging.getLogger("hercs.replay")


class ReplayTable:
    def __init__(self, *, config: HercsConfig, core: ReplayCore, log: EpisodeLogSink,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.core = core
        self.log = log
        self.clock = clock
        self.limiter, self.gate, self.lag_bound = admission_for(config)
        self._lock = threading.Lock()
        self._commit_lock = threading.Lock()
        """Held by the one thread whose group is being logged (taken before `_lock`)."""
        self._parked = ParkedCalls(
            waiting_inserts_per_actor=config.replay.waiting_inserts_per_actor)
        self.lags = PolicyLagLedger(config.training.episodes_per_cycle,
                                    prefetch_depth=config.learner.prefetch_depth)
        self.log_failures = 0
        """Inserts refused because their log append failed."""
        self._learner: str | None = None
        """The learner process whose kept samples the limiter counts from (`follow_learner`)."""

    # -- start-up --------------------------------------------------------------------------
    def recover(self, episodes: Iterable[tuple[int, EpisodeData]], *,
                state: ReplayState | None = None) -> list[tuple[int, int]]:
        """Store the log's episodes (not logged again; from its newest saved `state` on, if
        any: `ReplayCore.recover`) and restart the limiter balanced. Returns the (logged id,
        stored id) pairs that disagree (a log written by another buffer size): none normally."""
        with self._lock:
            mismatched, versions = self.core.recover(episodes, state)
            if self.gate is not None:
                self.gate.recover(versions.elements())
            count = self.core.store.num_inserted
            if count:
                self.limiter.restart_balanced(count)
                self.lags.recovered(self.core.newest_policy_version)
        return mismatched

    # -- inserts ---------------------------------------------------------------------------
    def insert(self, episode: EpisodeData, *, record: pb.Episode, waiter: Waiter[Stored],
               timeout_s: float | None = None) -> None:
        """Store `episode` when the limiter admits it, then `waiter.done(Stored)`.

        `record` is what goes into the log (the message as received). `timeout_s`: the
        caller's own timeout; a call still parked after it is answered `expired`.
        """
        key = insert_key(episode)
        with self._lock:
            known = self.core.lookup(*key)
            if known is not None:
                self.core.duplicates += 1
                waiter.done(Stored(episode, known, duplicate=True,
                                   next_policy_version=self._next_version(episode)))
                return
            parked = self._parked.joined(key)
            if parked is not None:  # a retry of a call still waiting: answer both together
                parked.waiters.append(waiter)
                parked.deadline = self._deadline(timeout_s)
                return
            refusal = (self._parked.inserts.refusal(episode.actor_id)
                       or self.lags.future_refusal(episode.policy_version)
                       or self.core.implausible(episode))
            if refusal is None and self.gate is not None:
                refusal = self.gate.refuse_insert(episode.policy_version)
            if refusal is not None:
                self.core.count_reject(refusal[0])
                waiter.fail(*refusal)
                return
            if self.gate is not None:
                self.gate.admit(episode.policy_version)
            item = ParkedInsert([waiter], self._deadline(timeout_s), episode=episode,
                                 record=record)
            self._parked.park_insert(item)
            self._drain()
        self._commit()

    def _commit(self) -> None:
        """Log, store and acknowledge the admitted inserts, group by group, until none is left
        (docs/DESIGN.md §3, "commit"). Called without the table's lock held.

        Never waits for another thread's group: if one is in flight, that thread commits
        what this one admitted (it looks at the ready list again after releasing the commit
        lock), so a sample or insert worker returns at once."""
        while True:
            if not self._commit_lock.acquire(blocking=False):
                return
            try:
                self._commit_groups()
            finally:
                self._commit_lock.release()
            with self._lock:  # admitted while we held the commit lock, after our last look?
                if not self._parked.ready:
                    return

    def _commit_groups(self) -> None:
        """Log a group under the ids the store will give it, the next ones in order (nothing
        else inserts while the commit lock is held), then store and acknowledge it."""
        while True:
            with self._lock:
                group = self._parked.take_ready()
                if not group:
                    return
                first_id = self.core.store.num_inserted
                try:
                    check_unstored(self.core, group)
                except EpisodeIdConflict as exc:  # before anything is logged: no id disagrees
                    log.error("%s", exc)
                    self._refuse(group, Reason.INTERNAL, str(exc))
                    self._drain()
                    continue
            records = [(first_id + i, item.record) for i, item in enumerate(group)]
            try:
                self.log.append_many(records)  # durable (fsync) before any ack
                failure: Exception | None = None
            except Exception as exc:
                failure = exc
            with self._lock:
                if failure is None:
                    for episode_id, item in zip(range(first_id, first_id + len(group)), group,
                                                strict=True):
                        self._store(item, episode_id)
                else:
                    self.log_failures += len(group)
                    self._refuse(group, Reason.LOG_FAILED,
                                 f"episode not logged, so not stored: {failure}")
                self._drain()  # parked samples may wait for exactly these inserts
                state = (self.core.state({} if self.gate is None else +self.gate.stored)
                         if failure is None and self.log.rotation_due() else None)
            if state is not None:  # a bounded log's next segment, while no group is in flight
                start_segment(self.log, state)

    def _refuse(self, group: list[ParkedInsert], reason: Reason, detail: str) -> None:
        """Answer every call of an admitted group that will not be stored."""
        self.limiter.cancel_inserts(len(group))
        for item in group:
            self._parked.forget(item)
            if self.gate is not None:
                self.gate.cancel(item.episode.policy_version)
            for waiter in item.waiters:
                waiter.fail(reason, detail)

    def _store(self, item: ParkedInsert, episode_id: int) -> None:
        episode = item.episode
        self._parked.forget(item)
        result = self.core.insert(episode)  # not stored before (`check_unstored`): gets episode_id
        self.limiter.store_admitted()
        self.lags.stored(episode_id, episode.policy_version)
        if self.gate is not None:
            self.gate.store(episode.policy_version)
        next_version = self._next_version(episode)
        item.waiters[0].done(Stored(episode, episode_id, duplicate=False, energy=result.energy,
                                    cluster=result.cluster, next_policy_version=next_version))
        for waiter in item.waiters[1:]:  # the retries that joined the first call
            self.core.duplicates += 1
            waiter.done(Stored(episode, episode_id, duplicate=True,
                               next_policy_version=next_version))

    def _next_version(self, episode: EpisodeData) -> int:
        """For an ack: the oldest weights version the actor's next episode may use (0
        asynchronously without a lag bound)."""
        if self.gate is not None:
            return self.gate.next_policy_version(episode.policy_version)
        return self.lags.bound_next_version(self.lag_bound, self._next_episode_id())

    def _next_episode_id(self) -> int:
        """The id the next admitted insert will be stored under (after those admitted and
        not yet stored)."""
        return self.core.store.num_inserted + self.limiter.pending_inserts

    def _refuse_stale(self, item: ParkedInsert) -> bool:
        """The lag bound's check of an insert the limiter admits: True if it was refused
        (answered `stale_policy`, counted, forgotten)."""
        episode = item.episode
        refusal = self.lags.bound_refusal(self.lag_bound, episode.policy_version,
                                          self._next_episode_id())
        if refusal is None:
            return False
        self._parked.forget(item)
        self.core.count_reject(refusal[0])
        for waiter in item.waiters:
            waiter.fail(*refusal)
        return True

    # -- samples ---------------------------------------------------------------------------
    def sample(self, call: SampleCall, *, waiter: Waiter[ServedBatch],
               timeout_s: float | None = None) -> None:
        """Draw `call.num_minibatches` minibatches when the limiter admits them, then
        `waiter.done(ServedBatch)`. Raises `SampleRefused` (nothing parked) for a call no state of
        the limiter could ever admit."""
        if not self.limiter.could_ever_sample(call.num_minibatches):
            raise SampleRefused(
                f"SampleRequest.num_minibatches {call.num_minibatches}: the rate limiter "
                f"admits at most {self.limiter.max_admissible_sample():g} minibatches per "
                "request (replay.rate_tolerance_updates sets its window); ask for fewer")
        with self._lock:
            self.lags.announced(call.weights_version)
            self._learner = follow_learner(call, self._learner, self.limiter,
                                           self._parked.samples)
            self._parked.park_sample(ParkedSample([waiter], self._deadline(timeout_s),
                                                  call=call))
            self._drain()
        self._commit()  # the samples served may have admitted parked inserts

    def _serve(self, item: ParkedSample) -> None:
        call = item.call
        self.lags.serving(call.weights_version)
        served = self.core.sample(call.num_minibatches, call.batch_size)
        self.limiter.record_sample(call.num_minibatches)
        fitted_at = self._fitted_at()
        if self.gate is not None and self.gate.served(
                call.weights_version, failures=self.core.failures, fitted_at=fitted_at):
            log.warning("lockstep: cycle %d served with cluster model v%d: the refit due at %s "
                        "failed goals did not arrive within %.0f s (is the clusterer running?)",
                        call.weights_version, self._model_version(),
                        self.gate.next_fit(fitted_at), self.gate.cluster_wait_s)
        served = dataclasses.replace(
            served, policy_lags=self.lags.take_since_sample(), status=self._counters())
        for waiter in item.waiters:
            waiter.done(served)

    # -- the rate limiter's queues ---------------------------------------------------------
    def _drain(self) -> None:
        """Serve parked calls while the limiter admits them (docs/DESIGN.md §3, "drain"). In
        lockstep every parked sample that its cycle admits is served, in any order: each
        names its own cycle, and one that can no longer be served (a dead learner's, for a
        cycle no actor got the weights of) must not hold a restarted learner's behind it."""
        progressed = True
        while progressed:
            progressed = False
            parked = self._parked
            while parked.inserts and self.limiter.can_insert():
                item = parked.inserts.popleft()
                progressed = True
                if self._refuse_stale(item):
                    continue
                parked.ready.append(item)
                self.limiter.admit_insert()  # bounds inserts now, feeds samples once stored
            if self.gate is not None:
                ready: list[ParkedSample] = []
                waiting: deque[ParkedSample] = deque()
                for sample in parked.samples:
                    (ready if self._can_serve(sample) else waiting).append(sample)
                parked.samples = waiting
                for sample in ready:
                    self._serve(sample)
                progressed = progressed or bool(ready)
                continue
            while parked.samples and self._can_serve(parked.samples[0]):
                self._serve(parked.samples.popleft())
                progressed = True

    def _can_serve(self, item: ParkedSample) -> bool:
        if self.gate is None:
            return self.limiter.can_sample(item.call.num_minibatches)
        return self.gate.can_sample(item.call.weights_version, failures=self.core.failures,
                                    fitted_at=self._fitted_at(), now=self.clock())

    def _model_version(self) -> int:
        model = self.core.cluster_model
        return 0 if model is None else model.version

    def _fitted_at(self) -> int | None:
        """The failure count the current cluster model was fitted at (None: no model)."""
        model = self.core.cluster_model
        return None if model is None else model.failures_seen

    def _deadline(self, timeout_s: float | None) -> float | None:
        return None if timeout_s is None else self.clock() + timeout_s

    def expire(self) -> int:
        """Answer `expired` to every parked call past its deadline and drop it; returns how
        many calls were dropped. The order of the calls that stay is unchanged."""
        now = self.clock()
        with self._lock:
            expired = self._parked.take_expired(now)
            for parked in expired:
                for waiter in parked.waiters:
                    waiter.fail(Reason.EXPIRED, "the rate limiter held this call past its "
                                                "caller's timeout; the caller retries")
            if expired or self.gate is not None:
                # A dropped head of a queue may have held admissible calls; in lockstep a
                # sample may have waited long enough for a late cluster model.
                self._drain()
        self._commit()
        return len(expired)

    # -- cluster model, eval results, stored episodes ---------------------------------------
    def adopt_cluster_model(self, model: ClusterModel, record: pb.ClusterModel | None) -> bool:
        """Adopt a newer model (relabelling the store) and log `record` (None: it is already
        in the log, e.g. recovered from it); False if not newer. Raises ValueError for a model
        of the wrong k (nothing changes)."""
        with self._lock:
            if not self.core.set_cluster_model(model):
                return False
            if record is not None:
                self.log.append_cluster_model(record)
            if self.gate is not None:
                self._drain()  # a lockstep sample may wait for exactly this model
        self._commit()
        return True

    def clusterer_state(self) -> ClustererSnapshot:
        """What a (re)started clusterer continues from."""
        with self._lock:
            return ClustererSnapshot(failed_goals=self.core.failed_goals(),
                                     failures_seen=self.core.failures,
                                     episodes_seen=self.core.inserts,
                                     model_version=self._model_version())

    def log_eval_result(self, record: pb.EvalResult) -> None:
        with self._lock:
            self.log.append_eval_result(record)

    def stored_episode(self, episode_id: int) -> tuple[EpisodeData | None, int, int]:
        """(the episode or None, first stored id, one past the last id)."""
        with self._lock:
            store = self.core.store
            return (store.episode(episode_id), store.num_inserted - store.size,
                    store.num_inserted)

    def count_reject(self, reason: Reason) -> None:
        with self._lock:
            self.core.count_reject(reason)

    def cluster_sizes(self) -> list[int]:
        with self._lock:
            return [int(c) for c in self.core.cluster_sizes()]

    def status(self) -> ReplayCounters:
        """The counters as one consistent snapshot (`ReplayStatus`, and each served batch's)."""
        with self._lock:
            return self._counters()

    def _counters(self) -> ReplayCounters:
        core = self.core
        waiting_inserts, waiting_samples = self._parked.waiting()
        return ReplayCounters(
            size_episodes=core.store.size, size_transitions=core.store.num_transitions,
            inserts=core.inserts, duplicates=core.duplicates, samples=core.samples,
            rate_limiter=("lockstep" if self.gate is not None else
                          self.limiter.describe(inserts_waiting=waiting_inserts,
                                                samples_waiting=waiting_samples)),
            rejects=dict(core.rejects),
            cluster_sizes=[int(c) for c in core.cluster_sizes()],
            cluster_model_version=self._model_version(), env_steps=core.env_steps,
            policy_lag=self.lags.mean_schedule_lag,
            policy_lag_request=self.lags.mean_request_lag,
            buffer_moved_share=core.buffer_moved_share,
            inserts_waiting=waiting_inserts, samples_waiting=waiting_samples,
        )

