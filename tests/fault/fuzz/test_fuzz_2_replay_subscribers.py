"""Hostile input to the replay's subscribers: cluster models and eval results."""

from __future__ import annotations

import dataclasses

import pytest

from hercs.proto import hercs_pb2 as pb
from hercs.run.runlog import MAX_SEQUENCE
from tests.fault.fuzz.oracles import replay_eval_verdict
from tests.fault.fuzz.probes import Probe, make_eval, make_model, run_barrage
from tests.fault.fuzz.runs import KR, MAX_BYTES, VALID
from tests.fault.fuzz.strategies import cluster_model_probes, eval_result_probes
from tests.fault.fuzz.world import World, check_expect, sent

pytestmark = [pytest.mark.integration, pytest.mark.timeout(420)]


def test_replay_cluster_model_subscriber_adopts_only_valid_newer_models(world: World) -> None:
    w = world
    bases = [make_model(v, v).SerializeToString() for v in (1, 2, 3)]

    def barrage(probes: list[Probe]) -> None:
        for probe in probes:
            verdict = w.model_oracle(probe.payload)  # in send order: the replay's order
            check_expect(probe, verdict)
            if verdict == "adopted":
                w.ledger.models.append(w.model_oracle.version)
            elif verdict != "ignored":
                w.ledger.replay_rejects[verdict] += 1
            w.model_pub.put(probe.payload)
        sent(w, "cluster/model", probes)

    run_barrage(barrage, cluster_model_probes(), bases, MAX_BYTES, examples=55)
    w.check_replay_counters()


def test_replay_eval_result_subscriber_logs_only_valid_results(world: World) -> None:
    w = world
    bases = [make_eval(e, 2 * e).SerializeToString() for e in (1, 2, 3)]

    def barrage(probes: list[Probe]) -> None:
        for probe in probes:
            verdict = replay_eval_verdict(probe.payload)
            if probe.expect == VALID and pb.EvalResult.FromString(probe.payload).epoch > \
                    MAX_SEQUENCE:
                probe = dataclasses.replace(probe, expect="bad_value")
            check_expect(probe, verdict)
            if verdict == VALID:
                w.ledger.replay_evals.append(pb.EvalResult.FromString(probe.payload))
            else:
                w.ledger.replay_rejects[verdict] += 1
            w.puts[KR.eval_result].put(probe.payload)
        sent(w, "eval/result (replay)", probes)

    run_barrage(barrage, eval_result_probes(), bases, MAX_BYTES, examples=45)
    w.check_replay_counters()
