"""The rollout actor process (`hercs actor`): a thin Zenoh shell around `VectorRollout`.

It joins a run by asking the replay for its resolved config, takes the newest `Weights`, and
hands one exploring episode per env to the `Inserter` as `(actor_id=<ident>@<incarnation>, seq)`;
the incarnation is the start time, so a restarted actor never reuses a stored pair. Each
episode waits for the weights the schedule asks for (hercs.actors.weights_schedule), and
backpressure reaches the env through the blocking `Inserter.submit`. A stop flushes the queue
for at most `STOP_FLUSH_S`; once `RunProgress` says the run is finished the queue is given up
at once, since no learner will sample those episodes and retrying them would keep the actor
alive past its run (a scheduler would record the job as cancelled).
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np

from hercs.actors.actor_identity import LatestWeights, incarnation
from hercs.actors.actor_metrics import actor_metrics, unacked
from hercs.actors.builder import ActorBuilder
from hercs.actors.weights_schedule import Need
from hercs.config import HercsConfig
from hercs.errors import InvalidMessage
from hercs.net.service_shell import ServiceRuntime, join_run, service_main
from hercs.net.transport import TransportError
from hercs.proto import hercs_pb2 as pb
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.codec import episode_to_msg
from hercs.wire.episode import EpisodeData, EpisodeIdentity
from hercs.wire.validation import parse_message

log = logging.getLogger(__name__)

STOP_FLUSH_S = 3.0
"""On stop, queued inserts get this long to be acked before they are given up."""
METRICS_EVERY_EPISODES = 10


# --------------------------------------------------------------------------- the actor


class ActorService:
    """One actor on a joined run: policy, env, weights subscription and inserter.

    `run()` loops until `runtime.stop` is set and flushes the inserter; the caller then closes
    the transport and calls `close()`.
    """

    def __init__(self, *, runtime: ServiceRuntime, parts: ActorBuilder) -> None:
        self.runtime = runtime
        self.settings = parts.shell
        self.ident = runtime.ident
        self.actor_id = f"{self.ident}@{incarnation()}"
        """Identity on the wire: this process's incarnation after the id, so that a restart
        with the same `--id` starts new (actor_id, seq) pairs the replay has never seen."""
        self.spec = self.settings.spec
        self.policy = parts.actor_policy(self.ident)
        self.rng = parts.exploration_rng(self.ident)
        self.worker = parts.actor_envs(self.ident)
        self.weights_rejected = 0
        self._warn = WarnOncePerMinute(log)
        self._weights = LatestWeights()
        self._decoder = parts.decoder()
        transport, keys = runtime.transport, runtime.keys
        self.inserter = parts.inserter(
            request=lambda payload, timeout_s: transport.request(keys.insert, payload,
                                                                 timeout_s=timeout_s),
            actor_id=self.actor_id, on_crash=runtime.crashed)
        # Only the newest weights matter: a small ring that drops the oldest never stalls Zenoh.
        transport.subscribe(keys.weights, self._on_weights, latest=True, capacity=4,
                            drop_oldest=True)
        transport.subscribe(keys.progress, self._on_progress, latest=True, capacity=4,
                            drop_oldest=True)
        self.run_finished = threading.Event()
        self.episodes = 0
        self.schedule = parts.schedule()
        """What the next episode's weights must be (lockstep, the lag bound)."""

    def _on_weights(self, key: str, raw: bytes) -> None:
        """Subscription thread: decode, check, offer. Never touches the policy itself."""
        try:
            weights = self._decoder.decode(self._decoder.parse(raw))
        except InvalidMessage as exc:
            self.weights_rejected += 1
            self._warn.warn(f"weights:{exc.reason}",
                            f"ignored a Weights message on {key}: {exc}; keeping the current "
                            "policy")
            return
        self._weights.offer(weights)

    def _on_progress(self, key: str, raw: bytes) -> None:
        """The learner's `RunProgress`: once the run is finished this actor has no more use."""
        try:
            progress = parse_message(raw, pb.RunProgress,
                                     max_bytes=self.settings.max_message_bytes)
        except InvalidMessage as exc:
            self._warn.warn(f"progress:{exc.reason}", f"ignored a RunProgress on {key}: {exc}")
            return
        if progress.finished and not self.run_finished.is_set():
            log.info("actor %s: run %r finished (%d epochs); stopping", self.ident,
                     self.settings.run, progress.epochs)
            self.run_finished.set()
            self.inserter.abort()  # now, not after the episode at hand: nothing is retried
            self.runtime.stop.set()

    def _act(self, o: np.ndarray, g: np.ndarray) -> np.ndarray:
        return self.policy.act(o, g, explore=True, rng=self.rng)

    def run(self) -> int:
        settings, stop = self.settings, self.runtime.stop
        log.info("actor %s (wire id %s): run %r, task %s, method %s", self.ident,
                 self.actor_id, settings.run, self.spec.name, settings.method)
        if self.schedule.lockstep and self.worker.num_envs > settings.episodes_per_cycle:
            log.warning("lockstep with %d envs per process and %d episodes per cycle: the "
                        "replay refuses the surplus of every cycle (cycle_full)",
                        self.worker.num_envs, settings.episodes_per_cycle)
        window = (time.monotonic(), self.worker.env_steps)
        self.publish_metrics(steps_per_s=0.0)
        try:
            while not stop.is_set():
                self._adopt_newest()
                if not self._await_weights():
                    break
                acted_with = self.policy.version
                superseded_before = self.inserter.counters.superseded
                made = self.worker.run_episodes(self._act, EpisodeIdentity(
                    actor_id=self.actor_id, first_seq=self.episodes, policy_version=acted_with))
                if not self._submit(made):
                    break  # stopped while the queue was full: the rest are not sent
                if self.schedule.lockstep and not self._await_outcome(acted_with,
                                                                      superseded_before):
                    break
                if self.episodes % METRICS_EVERY_EPISODES < self.worker.num_envs:
                    now = time.monotonic()
                    rate = (self.worker.env_steps - window[1]) / max(now - window[0], 1e-9)
                    window = (now, self.worker.env_steps)
                    self.publish_metrics(steps_per_s=rate)
        finally:
            self.inserter.close(timeout_s=0.0 if self.run_finished.is_set() else STOP_FLUSH_S)
            self.publish_metrics(steps_per_s=0.0)
        c = self.inserter.counters
        log.info("actor %s stopping: %d episodes, %d acked (%d duplicate: a retry of one "
                 "already stored), %d superseded, %d dropped, %d given up unacked, %d retries",
                 self.ident, self.episodes, c.acked, c.duplicates, c.superseded, c.dropped,
                 self.unacked, c.retries)
        return 0

    def _submit(self, episodes: list[EpisodeData]) -> bool:
        """Hand each episode to the inserter; False if stopped while it was full."""
        for episode in episodes:
            msg = episode_to_msg(episode, run=self.settings.run, task=self.spec.name)
            if not self.inserter.submit(episode.seq, msg.SerializeToString(),
                                        stop=self.runtime.stop):
                return False
            self.episodes += 1
        return True

    def _adopt_newest(self) -> None:
        newest = self._weights.take()
        if newest is not None:
            self.policy.load(newest)

    def _await_weights(self) -> bool:
        """Wait for what the schedule asks of the next episode's weights (`WeightsSchedule`);
        False if stopped."""
        stop = self.runtime.stop
        wait = self.schedule.before_episode(
            policy_version=self.policy.version,
            latest_ack_version=self.inserter.latest_next_policy_version)
        if wait.need is Need.NOTHING:
            return not stop.is_set()
        if wait.need is Need.NEXT_ARRIVAL:
            while not stop.is_set():
                self._weights.wait(0.5)
                newest = self._weights.take()
                if newest is not None:
                    self.policy.load(newest)
                    return True
            return False
        while self.policy.version < wait.version:
            if stop.is_set():
                return False
            self._weights.wait(0.5)
            self._adopt_newest()
        return not stop.is_set()

    def _await_outcome(self, acted_with: int, superseded_before: int) -> bool:
        """Lockstep: wait for the inserts of the episodes just submitted to end, and tell the
        schedule how they ended. False if stopped."""
        if not self.inserter.wait_idle(stop=self.runtime.stop):
            return False
        self.schedule.after_outcome(
            acted_with=acted_with, newest_ack_version=self.inserter.newest_next_policy_version,
            superseded=self.inserter.counters.superseded > superseded_before)
        return True

    @property
    def unacked(self) -> int:
        return unacked(self.episodes, self.inserter.counters)

    def publish_metrics(self, *, steps_per_s: float) -> None:
        try:
            self.runtime.publish_metrics(actor_metrics(
                self.inserter.counters, env_steps=self.worker.env_steps,
                episodes=self.episodes, steps_per_s=steps_per_s,
                policy_version=self.policy.version, weights_rejected=self.weights_rejected))
        except TransportError as exc:  # metrics are best effort
            self._warn.warn("metrics", f"could not publish metrics: {exc}")

    def close(self) -> None:
        """After the transport is closed: wait for the sender thread, close the env."""
        if not self.inserter.join(2.0):
            log.warning("actor %s: inserter thread still running at exit", self.ident)
        self.worker.close()


def run(config: HercsConfig, *, ident: str | None = None) -> int:
    """`hercs actor`: join `config.run.name` and collect episodes until SIGTERM/SIGINT."""
    return service_main(role="actor", config=config, ident=ident, body=_work)


def _work(runtime: ServiceRuntime) -> int:
    joined = join_run(runtime, runtime.config)  # the run's config, served by its replay
    if joined is None:  # stopped first
        return 0
    service = ActorService(runtime=runtime, parts=ActorBuilder(joined))
    try:
        return service.run()
    finally:
        runtime.close()  # also ends an insert still in flight after the flush deadline
        service.close()
