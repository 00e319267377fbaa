"""Hostile input to the actor's and the evaluator's subscribers: weights, eval requests,
run progress."""

from __future__ import annotations

import pytest

from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from tests.fault.fuzz.oracles import parse_verdict, weights_verdict
from tests.fault.fuzz.probes import BASE_WEIGHTS, Probe, make_weights, run_barrage
from tests.fault.fuzz.runs import KA, MAX_BYTES, VALID
from tests.fault.fuzz.strategies import progress_probes, weights_probes
from tests.fault.fuzz.world import World, account_weights, check_evaluator, check_expect, sent

pytestmark = [pytest.mark.integration, pytest.mark.timeout(420)]


def test_actor_and_evaluator_weights_subscribers_adopt_only_valid_weights(world: World) -> None:
    w = world
    bases = [m.SerializeToString() for m in BASE_WEIGHTS]

    def barrage(probes: list[Probe]) -> None:
        for probe in probes:
            verdict, msg = weights_verdict(probe.payload)
            check_expect(probe, verdict)
            account_weights(w, verdict, msg, actor=True)
            w.weights_pub.put(probe.payload)
        sent(w, "weights", probes)

    run_barrage(barrage, weights_probes(), bases, MAX_BYTES, examples=75)
    final = make_weights(version=4_000_000_001, epoch=2, evaluate=True, seed=6)
    w.weights_pub.put(final.SerializeToString())
    account_weights(w, VALID, final, actor=True)
    versions = w.actor_replay.next_versions(lambda v: v == final.version, "with the last weights")
    assert set(versions) <= w.ledger.actor_versions, (
        f"the actor acted with versions {set(versions) - w.ledger.actor_versions} that no "
        "valid Weights carried")
    values = w.metrics_of("actor", lambda m: m["policy_version"] == final.version,
                          "the last weights adopted")
    assert 0 < values["weights_rejected"] <= w.ledger.actor_rejects_at_most
    check_evaluator(w, (2, final.version))



def test_evaluator_eval_request_subscriber(world: World) -> None:
    w = world
    bases = [make_weights(version=2000 + i, epoch=10 + i, evaluate=True, seed=i)
             .SerializeToString() for i in range(2)]

    def barrage(probes: list[Probe]) -> None:
        for probe in probes:
            verdict, msg = weights_verdict(probe.payload)
            check_expect(probe, verdict)
            account_weights(w, verdict, msg, actor=False)
            w.puts[KA.eval_request].put(probe.payload)
        sent(w, "eval/request", probes)

    run_barrage(barrage, weights_probes(evaluate=True), bases, MAX_BYTES, examples=30)
    final = make_weights(version=4_000_000_002, epoch=3, evaluate=True, seed=7)
    w.puts[KA.eval_request].put(final.SerializeToString())
    account_weights(w, VALID, final, actor=False)
    check_evaluator(w, (3, final.version))


def test_actor_progress_subscriber_ignores_bad_progress(world: World) -> None:
    w = world
    bases = [pb.RunProgress(schema_version=SCHEMA_VERSION, epoch=1, epochs=9).SerializeToString()]
    verdict_of = parse_verdict(pb.RunProgress, MAX_BYTES)

    def barrage(probes: list[Probe]) -> None:
        sending = []
        for probe in probes:
            verdict = verdict_of(probe.payload)
            check_expect(probe, verdict)
            if verdict == VALID and pb.RunProgress.FromString(probe.payload).finished:
                w.ledger.skipped["run/progress (valid, finished)"] += 1
                continue  # valid: the actor would rightly stop
            sending.append(probe)
            w.puts[KA.progress].put(probe.payload)
        sent(w, "run/progress", sending)

    run_barrage(barrage, progress_probes(), bases, MAX_BYTES, examples=20)
    versions = w.actor_replay.next_versions(lambda v: True, "after the progress messages")
    w.actor_replay.next_versions(lambda v: True, "after the progress messages")
    assert set(versions) <= w.ledger.actor_versions
    w.assert_running()
