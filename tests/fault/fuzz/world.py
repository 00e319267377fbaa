"""The world the barrages share (services, stand-ins, ledger) and the checks that several
barrages make."""

from __future__ import annotations

import queue
import time
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hercs.config import HercsConfig
from hercs.net.transport import RemoteError, Transport, TransportError
from hercs.proto import hercs_pb2 as pb
from tests.fault.fuzz.oracles import ModelOracle
from tests.fault.fuzz.probes import Probe
from tests.fault.fuzz.runs import ACTOR_CONFIG, LOG_PROBLEMS, REQUEST_TIMEOUT_S, VALID, WAIT_S
from tests.fault.fuzz.standins import ActorRunReplay, LearnerRunReplay
from tests.integration.services import ServiceProcess


@dataclass
class Ledger:
    """What was sent, and what the services must therefore report."""

    sent: Counter[str] = field(default_factory=Counter)
    skipped: Counter[str] = field(default_factory=Counter)
    replay_rejects: Counter[str] = field(default_factory=Counter)
    stored: dict[int, pb.Episode] = field(default_factory=dict)
    """Episode id → the stored episode as the replay must serve it back."""
    keys: dict[tuple[str, int], int] = field(default_factory=dict)
    duplicates: int = 0
    models: list[int] = field(default_factory=list)
    """Versions of the cluster models the replay adopted (and logged), in order."""
    replay_evals: list[pb.EvalResult] = field(default_factory=list)
    header_rejects: Counter[str] = field(default_factory=Counter)
    valid_sent: Counter[str] = field(default_factory=Counter)
    """Endpoint → the valid payloads sent to it, for the endpoints that take only so many."""
    actor_versions: set[int] = field(default_factory=set)
    """Versions of valid weights: the only ones the actor may act with."""
    actor_rejects_at_most: int = 0
    evaluator_rejects: int = 0
    eval_keys: set[tuple[int, int]] = field(default_factory=set)
    """(epoch, version) of valid evaluate=True weights: the only results the evaluator may
    publish."""
    evaluated: set[tuple[int, int]] = field(default_factory=set)
    """(epoch, version) of the results the evaluator published."""
    bad_batches: int = 0


@dataclass
class World:
    tmp: Path
    client: Transport
    procs: dict[str, ServiceProcess]
    configs: dict[str, HercsConfig]
    actor_replay: ActorRunReplay
    learner_replay: LearnerRunReplay
    pool: ThreadPoolExecutor
    ledger: Ledger
    model_oracle: ModelOracle
    weights_pub: Any
    model_pub: Any
    puts: dict[str, Any]
    status: queue.Queue[pb.ReplayStatus]
    metrics: dict[str, queue.Queue[dict[str, float]]]
    eval_results: queue.Queue[pb.EvalResult]
    learner_weights: queue.Queue[pb.Weights]

    def assert_running(self) -> None:
        for name, proc in self.procs.items():
            code = proc.proc.poll()
            assert code is None, f"{name} exited with {code}:\n{proc.log_text()[-4000:]}"

    def assert_logs_clean(self) -> None:
        for name, proc in self.procs.items():
            text = proc.log_text()
            bad = [line for line in text.splitlines() if LOG_PROBLEMS.search(line)]
            assert not bad, f"{name}'s log:\n" + text[-6000:]

    def ask(self, key: str, payloads: list[bytes]) -> list[tuple[bytes | None, str, str]]:
        """Each payload as a query, several in flight: (reply or None, reason, detail)."""

        def one(payload: bytes) -> tuple[bytes | None, str, str]:
            try:
                return self.client.request(key, payload, timeout_s=REQUEST_TIMEOUT_S), "", ""
            except RemoteError as exc:
                return None, exc.reason, exc.detail
            except TransportError as exc:  # a timeout: the service hung on this payload
                return None, "no-reply", str(exc)

        return list(self.pool.map(one, payloads))

    def replay_status(self, until: Callable[[pb.ReplayStatus], bool], what: str
                      ) -> pb.ReplayStatus:
        """The first ReplayStatus (they come once a second) that satisfies `until`."""
        deadline = time.monotonic() + WAIT_S
        last = None
        while time.monotonic() < deadline:
            try:
                last = self.status.get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                break
            if until(last):
                return last
        raise AssertionError(f"no ReplayStatus with {what} within {WAIT_S} s; last: {last}")

    def metrics_of(self, role: str, until: Callable[[dict[str, float]], bool], what: str
                   ) -> dict[str, float]:
        deadline = time.monotonic() + WAIT_S
        last = None
        while time.monotonic() < deadline:
            try:
                last = self.metrics[role].get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                break
            if until(last):
                return last
        raise AssertionError(f"no {role} metrics with {what} within {WAIT_S} s; last: {last}")

    def check_replay_counters(self) -> pb.ReplayStatus:
        """ReplayStatus must show exactly the rejects, episodes and duplicates of the ledger."""
        expected = {r: n for r, n in self.ledger.replay_rejects.items() if n}
        st_ = self.replay_status(lambda s: dict(s.rejects) == expected
                                 and s.size_episodes == len(self.ledger.stored),
                                 f"rejects {expected} and {len(self.ledger.stored)} episodes")
        assert st_.inserts == len(self.ledger.stored)
        assert st_.duplicates == self.ledger.duplicates
        assert st_.cluster_model_version == self.model_oracle.version
        return st_


def sent(w: World, endpoint: str, probes: list[Probe]) -> None:
    w.ledger.sent[endpoint] += len(probes)
    w.assert_running()


def check_expect(probe: Probe, verdict: str) -> None:
    """Where the generator knows the reason, the oracle (the service's own decoders) must
    agree: the broken field is caught, and caught for what it is."""
    if probe.expect is not None:
        assert verdict == probe.expect, f"{probe}: the decoders say {verdict!r}"


def checked_verdicts(probes: list[Probe], verdict_of: Callable[[bytes], str]) -> list[str]:
    """Each probe's verdict by the oracle, checked against what its generator expected."""
    verdicts = [verdict_of(p.payload) for p in probes]
    for probe, verdict in zip(probes, verdicts, strict=True):
        check_expect(probe, verdict)
    return verdicts


def capped_verdicts(w: World, probes: list[Probe], verdict_of: Callable[[bytes], str],
                    endpoint: str, cap: int, skipped_as: str) -> list[tuple[Probe, str]]:
    """The probes to send to `endpoint` with their checked verdicts: every invalid one, and
    the valid ones until it has had `cap` in all (each a costly or lasting effect); the valid
    ones past that are counted as skipped, under `skipped_as`."""
    kept = []
    for probe, verdict in zip(probes, checked_verdicts(probes, verdict_of), strict=True):
        if verdict == VALID:
            if w.ledger.valid_sent[endpoint] >= cap:
                w.ledger.skipped[skipped_as] += 1
                continue
            w.ledger.valid_sent[endpoint] += 1
        kept.append((probe, verdict))
    return kept


def asked_valid(w: World, key: str, probes: list[Probe], verdicts: list[str],
                ) -> Iterator[tuple[Probe, bytes | None, str, str]]:
    """Asks the replay's queryable `key` with every probe, several in flight: each invalid one
    must come back as an error reply of its verdict (a replay reject, counted); the valid ones
    are yielded with their (reply, reason, detail) for the test to check."""
    answers = w.ask(key, [p.payload for p in probes])
    for probe, verdict, (reply, reason, detail) in zip(probes, verdicts, answers, strict=True):
        if verdict != VALID:
            assert (reply, reason) == (None, verdict) and detail, (probe, reason, detail)
            w.ledger.replay_rejects[verdict] += 1
            continue
        yield probe, reply, reason, detail



def check_clusterer(w: World) -> None:
    expected = {f"rejected_{r}": float(n) for r, n in w.ledger.header_rejects.items()}
    episodes = len(w.ledger.stored) + w.ledger.valid_sent["replay/inserted"]
    values = w.metrics_of(
        "clusterer", lambda m: m["episodes_seen"] == episodes
        and {k: v for k, v in m.items() if k.startswith("rejected_")} == expected,
        f"{episodes} episodes and {expected}")
    assert values["rejected"] == sum(w.ledger.header_rejects.values())
    assert values["model_version"] == 0 and values["refits"] == 0



def account_weights(w: World, verdict: str, msg: pb.Weights | None, *, actor: bool) -> None:
    """Book one Weights message for the actor (if it gets it) and the evaluator."""
    if actor:
        if verdict == VALID:
            assert msg is not None
            w.ledger.actor_versions.add(int(msg.version))
        else:
            w.ledger.actor_rejects_at_most += 1
    if msg is None or (msg.evaluate and verdict != VALID):  # parse error or bad eval request
        w.ledger.evaluator_rejects += 1
    elif msg.evaluate and msg.epoch > ACTOR_CONFIG.training.epochs:
        w.ledger.evaluator_rejects += 1  # valid weights, but an epoch the run never reaches
    elif msg.evaluate:
        w.ledger.eval_keys.add((int(msg.epoch), int(msg.version)))


def check_evaluator(w: World, last: tuple[int, int]) -> None:
    """The evaluator published results for exactly the valid eval requests (in order, so
    `last`, sent last, comes last) and counted every bad one."""
    evaluated = w.ledger.evaluated
    deadline = time.monotonic() + WAIT_S
    while last not in evaluated:
        try:
            result = w.eval_results.get(timeout=max(deadline - time.monotonic(), 0.01))
        except queue.Empty:
            raise AssertionError(f"no result for {last}; got {sorted(evaluated)}") from None
        evaluated.add((int(result.epoch), int(result.weights_version)))
    assert evaluated == w.ledger.eval_keys, (
        f"evaluated but not valid: {evaluated - w.ledger.eval_keys}; valid but not evaluated: "
        f"{w.ledger.eval_keys - evaluated}")
    values = w.metrics_of("evaluator", lambda m: m["policy_version"] == last[1],
                          f"version {last[1]} evaluated")
    assert values["weights_rejected"] == w.ledger.evaluator_rejects
