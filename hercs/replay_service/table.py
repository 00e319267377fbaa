"""The replay table, the one object the replay service is (Reverb's `Table` is the model).

`ReplayTable` owns the episode store, the sampler, the o/g normalisers, the cluster model and
the counters, the rate limiter and its schedule's admission (hercs.replay_service.admission),
the parked calls (hercs.replay_service.parked_calls), the log's group commit and the
`PolicyLagLedger`. Invariants: an (actor_id, seq) pair is stored at most once; every stored
episode carries its cluster under the current model (-1 before one); normaliser statistics
cover every stored episode. Every public method takes the table's lock and waiters are called
under it, so they must only hand their answer over.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import threading
import time
from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from hercs.config import EnergyConfig
from hercs.errors import ConfigError
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.admission import Admission
from hercs.replay_service.energy import trajectory_energy
from hercs.replay_service.her import relabel
from hercs.replay_service.learner_follow import follow_learner
from hercs.replay_service.lockstep import LOCKSTEP_CLUSTER_WAIT_S
from hercs.replay_service.normalizers import EpisodeNormalizers
from hercs.replay_service.parked_calls import InsertKey, ParkedCalls, check_unstored, insert_key
from hercs.replay_service.policy_lag import PolicyLagLedger
from hercs.replay_service.rate_limiter import SampleToInsertRatio
from hercs.replay_service.store import EpisodeStore
from hercs.replay_service.table_calls import (
    ClustererSnapshot,
    EpisodeIdConflict,
    EpisodeLogSink,
    NoLog,
    ParkedInsert,
    ParkedSample,
    SampleCall,
    SampleRefused,
    Stored,
    Waiter,
    start_segment,
)
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.samplers.base import EpisodeSampler
from hercs.rl.task_registry import TaskSpec
from hercs.run.runlog.format import EpisodeLogError
from hercs.wire.episode import EpisodeData
from hercs.wire.replay_state import ReplayState
from hercs.wire.served import ReplayCounters, ServedBatch

__all__ = ["LOCKSTEP_CLUSTER_WAIT_S", "ClustererSnapshot", "EpisodeLogSink", "ReplayTable",
           "SampleCall", "SampleRefused", "Stored", "Waiter"]  # calls and answers: table_calls

log = logging.getLogger("hercs.replay")

STATUS_SNAPSHOTS = 64
"""Served batches whose counters `status_at` still answers with: far more than a learner
samples ahead of its epoch's end (`learner.prefetch_depth` batches)."""


class ReplayTable:
    def __init__(self, *, spec: TaskSpec, store: EpisodeStore, sampler: EpisodeSampler,
                 normalizers: EpisodeNormalizers, lags: PolicyLagLedger,
                 limiter: SampleToInsertRatio, admission: Admission, energy: EnergyConfig,
                 clusters: int, future_p: float, failed_goals_kept: int,
                 waiting_inserts_per_actor: int, rng: np.random.Generator,
                 log: EpisodeLogSink | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """The parts as `hercs.replay_service.builder.ReplayBuilder` makes them from a run's
        config (`lags` shared with `admission`, which owns the schedule's rules over
        `limiter`); `clusters`: `cluster.k`; `future_p`: HER's relabel probability;
        `failed_goals_kept`: `cluster.fgb_size`, the newest failed goals a restarted clusterer
        gets back. `log` None: an in-process table that logs nothing (a bench's, a study's)."""
        self.spec = spec
        self.rng = rng
        self.log: EpisodeLogSink = NoLog() if log is None else log
        self.clock = clock
        self.store = store
        self.sampler = sampler
        self.normalizers = normalizers
        self.energy = energy
        self.clusters = clusters
        self.future_p = future_p
        self.cluster_model: ClusterModel | None = None
        self.lags = lags
        self.limiter, self.admission = limiter, admission
        self._lock = threading.Lock()
        self._commit_lock = threading.Lock()
        """Held by the one thread whose group is being logged (taken before `_lock`)."""
        self._parked = ParkedCalls(waiting_inserts_per_actor=waiting_inserts_per_actor)
        self._seen: OrderedDict[InsertKey, int] = OrderedDict()
        """(actor_id, seq) -> episode id, for the episodes still in the ring."""
        self._learner: str | None = None
        """The learner process whose kept samples the limiter counts from (`follow_learner`)."""
        self._status_at: OrderedDict[int, ReplayCounters] = OrderedDict()
        """samples served -> the counters when that batch was drawn, for the newest
        `STATUS_SNAPSHOTS` batches (`status_at`)."""
        self.inserts = 0
        self.duplicates = 0
        self.samples = 0
        self.env_steps = 0
        self.rejects: Counter[str] = Counter()
        self.log_failures = 0
        """Inserts refused because their log append failed."""
        self.cluster_draws_total = np.zeros(clusters, np.int64)
        self.newest_policy_version: int | None = None
        """The newest weights version any stored episode was acted with (None before the
        first): after a restart, a floor under the learner's newest weights (they existed)."""
        self.failures = 0
        """Stored episodes that failed (not `TaskSpec.is_success` at their last step)."""
        self.recent_failed_goals: deque[np.ndarray] = deque(maxlen=failed_goals_kept)
        """Desired goals of the newest failed episodes, oldest first: what a restarted
        clusterer refills its failed-goal buffer with."""

    # -- start-up: the episode log ---------------------------------------------------------
    def recover(self, episodes: Iterable[tuple[int, EpisodeData]], *,
                state: ReplayState | None = None) -> list[tuple[int, int]]:
        """Store a restarted replay's logged (id, episode) pairs (not logged again), or with the
        log's newest `state`, restore that state (the episodes before its first_held_id are
        skipped, those up to its next_episode_id restored) and store only the later ones; then
        restart the limiter balanced. Returns the (logged id, stored id) pairs that disagree (a
        log written by another buffer size): none normally."""
        with self._lock:
            versions: Counter[int] = Counter()
            if state is not None:
                held, episodes = split_at_state(episodes, state)
                self._restore(state, held)
                versions.update(state.stored_per_version)
            else:
                source = iter(episodes)
                first = next(source, None)
                if first is not None and first[0] != 0:
                    raise EpisodeLogError(
                        f"the episode log starts at episode {first[0]} and holds no replay "
                        "state to start from: its first segments were removed by hand; put "
                        "them back")
                episodes = itertools.chain([first] if first is not None else [], source)
            mismatched = []
            for episode_id, episode in episodes:
                stored = self._store_unadmitted(episode)
                if stored.episode_id != episode_id:
                    mismatched.append((episode_id, stored.episode_id))
                versions[episode.policy_version] += 1
            self.admission.recovered(versions.elements())
            count = self.store.num_inserted
            if count:
                self.limiter.restart_balanced(count)
                self.lags.recovered(self.newest_policy_version)
        return mismatched

    def _restore(self, state: ReplayState, held: Iterable[tuple[int, EpisodeData]]) -> None:
        """Start an empty table from `state` and the logged episodes from its `first_held_id`
        up to its `next_episode_id` − 1, in order: the same store, dedup keys, counts, failed
        goals and normalisers as the table that saved `state` (its cluster model is adopted
        afterwards, as after a replay of the whole log). Raises EpisodeLogError if `held` lacks
        an episode the store held."""
        if self.store.num_inserted:
            raise ConfigError("ReplayTable.recover: this table has stored episodes already")
        kept = state.next_episode_id - state.first_held_id
        if kept < min(state.next_episode_id, self.store.capacity_episodes):
            raise EpisodeLogError(
                f"the episode log's newest replay state keeps the {kept} episodes from id "
                f"{state.first_held_id} on, fewer than this replay's buffer of "
                f"{self.store.capacity_episodes} holds: it was written with a smaller "
                "replay.buffer_transitions; resume with the run's own, or start a new run")

        def with_energy() -> Iterator[tuple[int, EpisodeData, float]]:
            for episode_id, episode in held:
                self._remember(insert_key(episode), episode_id)
                self._saw_version(episode.policy_version)
                yield episode_id, episode, self._energy(episode)

        self.store.restore(with_energy(), next_id=state.next_episode_id)
        self.normalizers.load(state.o_stats, state.g_stats)
        self.failures = state.failures
        self.recent_failed_goals.clear()
        self.recent_failed_goals.extend(np.asarray(g, np.float32)
                                        for g in state.recent_failed_goals)
        self.inserts = state.next_episode_id
        self.env_steps = state.next_episode_id * self.spec.episode_steps

    def _state(self) -> ReplayState:
        """What this table derived from every episode stored so far, beyond the episodes its
        store holds (`hercs.wire.replay_state`): a bounded log's next segment starts with it."""
        held = self.store.episode_id
        o_stats, g_stats = self.normalizers.state()
        return ReplayState(
            next_episode_id=self.store.num_inserted,
            first_held_id=int(held.min()) if held.size else 0, failures=self.failures,
            recent_failed_goals=self._failed_goals(), o_stats=o_stats, g_stats=g_stats,
            cluster_model=self.cluster_model,
            stored_per_version=self.admission.stored_per_version())

    def store_episode(self, episode: EpisodeData) -> Stored:
        """Store `episode` now, without the limiter or the log: an in-process table's insert
        (a bench's, a study's, a test's). A retry of a stored one is answered as a duplicate."""
        with self._lock:
            return self._store_unadmitted(episode)

    def _store_unadmitted(self, episode: EpisodeData) -> Stored:
        return self._retry_of_stored(episode) or self._add(episode)

    # -- the stored episodes ---------------------------------------------------------------
    def _retry_of_stored(self, episode: EpisodeData) -> Stored | None:
        """The duplicate answer to a retry of a stored episode (counted), or None: the one
        place an insert is deduplicated (each insert passes it once, on arrival)."""
        known = self._seen.get(insert_key(episode))
        if known is None:
            return None
        self.duplicates += 1
        return Stored(episode, known, duplicate=True)

    def _add(self, episode: EpisodeData) -> Stored:
        """Store an episode that is not stored yet; it gets the next episode id."""
        energy = self._energy(episode)
        cluster = -1
        if self.cluster_model is not None:
            cluster = int(self.cluster_model.assign(episode.ag[-1:])[0])
        episode_id = self.store.insert(episode, energy=energy, cluster=cluster)
        self._remember(insert_key(episode), episode_id)
        self._saw_version(episode.policy_version)
        self.normalizers.update(episode, self.rng)
        if not self.spec.is_success(episode.ag[-1], episode.g[-1]):
            self.failures += 1
            self.recent_failed_goals.append(np.array(episode.g[-1], np.float32))
        self.inserts += 1
        self.env_steps += self.spec.episode_steps
        return Stored(episode, episode_id, duplicate=False, energy=energy, cluster=cluster)

    def _energy(self, episode: EpisodeData) -> float:
        """The episode's trajectory energy by its task's energy kind (0 where it has none),
        the same at insert and at a restore."""
        if self.spec.energy == "none":
            return 0.0
        return float(trajectory_energy(episode.ag, self.energy, self.spec.energy))

    def _remember(self, key: InsertKey, episode_id: int) -> None:
        self._seen[key] = episode_id
        # Forget pairs whose episode left the ring: the oldest entries go first.
        while len(self._seen) > self.store.capacity_episodes:
            self._seen.popitem(last=False)

    def _saw_version(self, policy_version: int) -> None:
        newest = self.newest_policy_version
        self.newest_policy_version = (int(policy_version) if newest is None
                                      else max(newest, int(policy_version)))

    def _failed_goals(self) -> np.ndarray:
        """(n ≤ fgb_size, goal_dim) float32: `recent_failed_goals` as one array."""
        if not self.recent_failed_goals:
            return np.zeros((0, self.spec.goal_dim), np.float32)
        return np.stack(list(self.recent_failed_goals))

    # -- inserts ---------------------------------------------------------------------------
    def insert(self, episode: EpisodeData, *, record: pb.Episode, waiter: Waiter[Stored],
               timeout_s: float | None = None) -> None:
        """Store `episode` when its admission allows, then `waiter.done(Stored)`.

        `record` is what goes into the log (the message as received). `timeout_s`: the
        caller's own timeout; a call still parked after it is answered `expired`.
        """
        with self._lock:
            retry = self._retry_of_stored(episode)
            if retry is not None:
                waiter.done(dataclasses.replace(
                    retry, next_policy_version=self._next_version(episode)))
                return
            parked = self._parked.joined(insert_key(episode))
            if parked is not None:  # a retry of a call still waiting: answer both together
                parked.waiters.append(waiter)
                parked.deadline = self._deadline(timeout_s)
                return
            refusal = (self._parked.inserts.refusal(episode.actor_id)
                       or self.lags.future_refusal(episode.policy_version)
                       or self.normalizers.implausible(episode)
                       or self.admission.refuse_insert(episode.policy_version))
            if refusal is not None:
                self.rejects[refusal[0]] += 1
                waiter.fail(*refusal)
                return
            self.admission.admit(episode.policy_version)
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
                first_id = self.store.num_inserted
                try:
                    check_unstored(self._seen, group)
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
                    for item in group:
                        self._store_admitted(item)
                else:
                    self.log_failures += len(group)
                    self._refuse(group, Reason.LOG_FAILED,
                                 f"episode not logged, so not stored: {failure}")
                self._drain()  # parked samples may wait for exactly these inserts
                state = (self._state() if failure is None and self.log.rotation_due()
                         else None)
            if state is not None:  # a bounded log's next segment, while no group is in flight
                start_segment(self.log, state)

    def _refuse(self, group: list[ParkedInsert], reason: Reason, detail: str) -> None:
        """Answer every call of an admitted group that will not be stored."""
        self.limiter.cancel_inserts(len(group))
        for item in group:
            self._parked.forget(item)
            self.admission.cancel(item.episode.policy_version)
            for waiter in item.waiters:
                waiter.fail(reason, detail)

    def _store_admitted(self, item: ParkedInsert) -> None:
        """Store a logged insert (`check_unstored` made sure it is new, so it gets the id it
        was logged under) and answer its call and the retries that joined it."""
        episode = item.episode
        self._parked.forget(item)
        stored = self._add(episode)
        self.limiter.store_admitted()
        self.lags.stored(stored.episode_id, episode.policy_version)
        self.admission.store(episode.policy_version)
        stored = dataclasses.replace(stored, next_policy_version=self._next_version(episode))
        item.waiters[0].done(stored)
        for waiter in item.waiters[1:]:  # the retries that joined the first call
            self.duplicates += 1
            waiter.done(Stored(episode, stored.episode_id, duplicate=True,
                               next_policy_version=stored.next_policy_version))

    def _next_version(self, episode: EpisodeData) -> int:
        """For an ack: the oldest weights version the actor's next episode may use."""
        return self.admission.next_policy_version(episode.policy_version,
                                                  self._next_episode_id())

    def _next_episode_id(self) -> int:
        """The id the next admitted insert will be stored under (after those admitted and
        not yet stored)."""
        return self.store.num_inserted + self.limiter.pending_inserts

    def _refuse_late(self, item: ParkedInsert) -> bool:
        """The admission's check of an insert the limiter admits (the lag bound's): True if
        it was refused (answered, counted, forgotten)."""
        refusal = self.admission.refuse_admitted(item.episode.policy_version,
                                                 self._next_episode_id())
        if refusal is None:
            return False
        self._parked.forget(item)
        self.rejects[refusal[0]] += 1
        for waiter in item.waiters:
            waiter.fail(*refusal)
        return True

    # -- samples ---------------------------------------------------------------------------
    def sample(self, call: SampleCall, *, waiter: Waiter[ServedBatch],
               timeout_s: float | None = None) -> None:
        """Draw `call.num_minibatches` minibatches when the admission serves them, then
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

    def draw(self, num_minibatches: int, batch_size: int) -> ServedBatch:
        """`num_minibatches` HER-relabelled minibatches of `batch_size` transitions now, with
        the normaliser statistics to train them with, and no limiter: an in-process table's
        sample (a bench's, a study's, a test's)."""
        with self._lock:
            return self._draw(num_minibatches, batch_size)

    def _draw(self, num_minibatches: int, batch_size: int) -> ServedBatch:
        draws = np.zeros(self.clusters, np.int64)
        out = []
        moved, sampled = 0, 0
        for _ in range(num_minibatches):
            slots, info = self.sampler.sample(self.store, batch_size, self.rng)
            draws += info.cluster_counts
            moved += int(self.store.moved[slots].sum())
            sampled += len(slots)
            out.append(relabel(self.store, slots, future_p=self.future_p,
                               reward_fn=self.spec.compute_reward, rng=self.rng))
        self.samples += num_minibatches
        self.cluster_draws_total += draws
        o_stats, g_stats = self.normalizers.state()
        return ServedBatch(minibatches=out, o_stats=o_stats, g_stats=g_stats,
                           cluster_draws=draws, sampled_moved=moved, sampled_transitions=sampled,
                           samples_served=self.samples, buffer_moved_share=self._moved_share())

    def _serve(self, item: ParkedSample) -> None:
        call = item.call
        self.lags.serving(call.weights_version)
        served = self._draw(call.num_minibatches, call.batch_size)
        self.limiter.record_sample(call.num_minibatches)
        warning = self.admission.served(call.weights_version, failures=self.failures,
                                        fitted_at=self._fitted_at(),
                                        model_version=self._model_version())
        if warning is not None:
            log.warning("%s", warning)
        served = dataclasses.replace(served, policy_lags=self.lags.take_since_sample())
        self._remember_status()
        for waiter in item.waiters:
            waiter.done(served)

    # -- the parked calls ------------------------------------------------------------------
    def _drain(self) -> None:
        """Admit parked inserts and serve parked samples while the limiter and the admission
        allow (docs/DESIGN.md §3, "drain"). Draining again with nothing changed does nothing."""
        progressed = True
        while progressed:
            progressed = False
            parked = self._parked
            while parked.inserts and self.limiter.can_insert():
                item = parked.inserts.popleft()
                progressed = True
                if self._refuse_late(item):
                    continue
                parked.ready.append(item)
                self.limiter.admit_insert()  # bounds inserts now, feeds samples once stored
            while ready := self.admission.take_servable(
                    parked.samples, failures=self.failures, fitted_at=self._fitted_at(),
                    now=self.clock()):
                for sample in ready:
                    self._serve(sample)
                progressed = True

    def _model_version(self) -> int:
        model = self.cluster_model
        return 0 if model is None else model.version

    def _fitted_at(self) -> int | None:
        """The failure count the current cluster model was fitted at (None: no model)."""
        model = self.cluster_model
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
            # A dropped head of a queue may have held admissible calls; in lockstep a sample
            # may have waited long enough for a late cluster model.
            self._drain()
        self._commit()
        return len(expired)

    # -- cluster model, eval results, stored episodes ---------------------------------------
    def adopt_cluster_model(self, model: ClusterModel, record: pb.ClusterModel | None) -> bool:
        """Adopt a newer model (relabelling the store) and log `record` (None: it is already
        in the log, e.g. recovered from it); False if not newer. Raises ValueError for a model
        of the wrong k (nothing changes)."""
        with self._lock:
            if self.cluster_model is not None and model.version <= self.cluster_model.version:
                return False
            if model.k != self.clusters:
                raise ValueError(f"ClusterModel has k={model.k}, this replay is configured "
                                 f"for cluster.k={self.clusters}; model ignored")
            self.cluster_model = model
            if self.store.size:
                self.store.set_clusters(model.assign(self.store.final_ag))
            if record is not None:
                self.log.append_cluster_model(record)
            self._drain()  # a lockstep sample may wait for exactly this model
        self._commit()
        return True

    def clusterer_state(self) -> ClustererSnapshot:
        """What a (re)started clusterer continues from."""
        with self._lock:
            return ClustererSnapshot(failed_goals=self._failed_goals(),
                                     failures_seen=self.failures, episodes_seen=self.inserts,
                                     model_version=self._model_version())

    def log_eval_result(self, record: pb.EvalResult) -> None:
        with self._lock:
            self.log.append_eval_result(record)

    def stored_episode(self, episode_id: int) -> tuple[EpisodeData | None, int, int]:
        """(the episode or None, first stored id, one past the last id)."""
        with self._lock:
            store = self.store
            return (store.episode(episode_id), store.num_inserted - store.size,
                    store.num_inserted)

    def count_reject(self, reason: Reason) -> None:
        with self._lock:
            self.rejects[reason] += 1

    def cluster_sizes(self) -> list[int]:
        with self._lock:
            return self._cluster_sizes()

    def _cluster_sizes(self) -> list[int]:
        labels = self.store.cluster
        return [int(c) for c in np.bincount(labels[labels >= 0],
                                            minlength=self.clusters)]

    def status(self) -> ReplayCounters:
        """The counters as one consistent snapshot (`ReplayStatus`)."""
        with self._lock:
            return self._counters()

    def _moved_share(self) -> float:
        """Share of the stored episodes whose achieved goal moved."""
        return self.store.moved_count / max(self.store.size, 1)

    def _remember_status(self) -> None:
        """Keep the counters of the batch just drawn, for `status_at`."""
        self._status_at[self.samples] = self._counters()
        while len(self._status_at) > STATUS_SNAPSHOTS:
            self._status_at.popitem(last=False)

    def status_at(self, samples: int) -> ReplayCounters:
        """The counters as they stood when the batch that brought `samples` to its value was
        served, while it is among the newest `STATUS_SNAPSHOTS`; otherwise (a restarted
        replay, an old or unknown count) the current ones, whose `samples` then differs."""
        with self._lock:
            held = self._status_at.get(samples)
            return held if held is not None else self._counters()

    def _counters(self) -> ReplayCounters:
        store = self.store
        waiting_inserts, waiting_samples = self._parked.waiting()
        return ReplayCounters(
            size_episodes=store.size, size_transitions=store.num_transitions,
            inserts=self.inserts, duplicates=self.duplicates, samples=self.samples,
            rate_limiter=self.admission.describe(inserts_waiting=waiting_inserts,
                                                 samples_waiting=waiting_samples),
            rejects=dict(self.rejects), cluster_sizes=self._cluster_sizes(),
            cluster_model_version=self._model_version(), env_steps=self.env_steps,
            policy_lag=self.lags.mean_schedule_lag,
            policy_lag_request=self.lags.mean_request_lag,
            buffer_moved_share=self._moved_share(),
            inserts_waiting=waiting_inserts, samples_waiting=waiting_samples,
        )


def split_at_state(episodes: Iterable[tuple[int, EpisodeData]], state: ReplayState
                   ) -> tuple[Iterator[tuple[int, EpisodeData]], Iterator[tuple[int, EpisodeData]]]:
    """A restarted replay's logged episodes, in id order, as (those `state` held: from its
    first_held_id to its next_episode_id − 1; the ones after it). Ids before first_held_id
    (in segments not deleted yet) are skipped. Consume the first before the second."""
    source = iter(episodes)
    after: list[tuple[int, EpisodeData]] = []

    def held() -> Iterator[tuple[int, EpisodeData]]:
        for pair in source:
            if pair[0] >= state.next_episode_id:
                after.append(pair)
                return
            if pair[0] >= state.first_held_id:
                yield pair

    def later() -> Iterator[tuple[int, EpisodeData]]:
        yield from after
        yield from source

    return held(), later()
