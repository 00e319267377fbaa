"""Hostile input to the learner: the replay's Batch replies and eval results."""

from __future__ import annotations

import csv
import time
from pathlib import Path

import pytest

from hercs.proto import hercs_pb2 as pb
from hercs.run.rundir import RunDir
from tests.fault.fuzz.oracles import batch_verdict, eval_verdict
from tests.fault.fuzz.probes import BASE_BATCHES, Probe, make_eval, run_barrage
from tests.fault.fuzz.runs import (
    CYCLES_PER_EPOCH,
    KL,
    LEARNER_EVAL_MAX_BYTES,
    MAX_VALID_BATCHES,
    RUN_L,
    VALID,
    WAIT_S,
)
from tests.fault.fuzz.strategies import batch_probes, eval_result_probes
from tests.fault.fuzz.world import World, capped_verdicts, check_expect, sent

pytestmark = [pytest.mark.integration, pytest.mark.timeout(420)]


def test_learner_skips_and_counts_bad_batches(world: World) -> None:
    w = world
    bases = [m.SerializeToString() for m in BASE_BATCHES]

    def barrage(probes: list[Probe]) -> None:
        sending = capped_verdicts(w, probes, batch_verdict, "replay/sample replies (learner)",
                                  MAX_VALID_BATCHES, "replay/sample replies (learner, valid)")
        w.ledger.bad_batches += sum(verdict != VALID for _, verdict in sending)
        w.learner_replay.answer([probe.payload for probe, _ in sending])
        sent(w, "replay/sample replies (learner)", [probe for probe, _ in sending])

    run_barrage(barrage, batch_probes(), bases, None, examples=50)
    assert not w.learner_replay.odd_requests, w.learner_replay.odd_requests[:3]


def test_learner_records_only_the_valid_eval_result(world: World) -> None:
    w = world
    w.learner_replay.valid.set()  # the learner trains: epochs end, and wait for results
    deadline = time.monotonic() + WAIT_S
    while True:
        weights = w.learner_weights.get(timeout=max(deadline - time.monotonic(), 0.01))
        if weights.evaluate and weights.epoch == 1:
            break
    version = int(weights.version)
    assert version == CYCLES_PER_EPOCH, "one version per cycle"

    def recorded(probe: Probe) -> bool:
        """Would the learner rightly record it: valid, for a pending epoch, of its weights."""
        if eval_verdict(probe.payload, limit=LEARNER_EVAL_MAX_BYTES) != VALID:
            return False
        msg = pb.EvalResult.FromString(probe.payload)
        return msg.epoch >= 1 and msg.weights_version == CYCLES_PER_EPOCH * msg.epoch

    # Epoch 1 and its own weights version: a broken value is caught by the checks of the
    # values, not by the version; a valid result would be recorded, so it is not sent.
    bases = [make_eval(1, version).SerializeToString(),
             make_eval(2, 2 * CYCLES_PER_EPOCH).SerializeToString()]

    def eval_barrage(probes: list[Probe]) -> None:
        sending = []
        for probe in probes:
            check_expect(probe, eval_verdict(probe.payload, limit=LEARNER_EVAL_MAX_BYTES))
            if recorded(probe):
                w.ledger.skipped["eval/result (learner, valid)"] += 1
                continue
            sending.append(probe)
            w.puts[KL.eval_result].put(probe.payload)
        sent(w, "eval/result (learner)", sending)

    run_barrage(eval_barrage, eval_result_probes(epoch=1, version=version), bases,
                LEARNER_EVAL_MAX_BYTES, examples=30)
    good = make_eval(1, version, success=0.625, distance=0.0425, episodes=8)
    w.puts[KL.eval_result].put(good.SerializeToString())
    values = w.metrics_of("learner", lambda m: m.get("epoch") == 1, "epoch 1 recorded")
    assert (values["success_rate"], values["mean_final_distance"]) == (0.625, 0.0425)
    assert values["weights_version"] == version
    assert values["bad_batches"] == w.ledger.bad_batches
    assert values["replay_size"] == 4242, "the counters of the epoch's last Batch, a valid one"
    with RunDir(Path(w.configs["learner"].run.run_dir) / RUN_L).metrics.open() as f:
        rows = list(csv.DictReader(f))
    assert [(r["epoch"], r["success_rate"], r["bad_batches"]) for r in rows] == [
        ("1", "0.625", str(w.ledger.bad_batches))]
