"""After every barrage: valid input is still served and adopted, the logs are clean, every
process exits 0 on SIGTERM and the replay logged exactly what the ledger says."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.run.runlog import read_cluster_models, read_episode_messages, read_eval_results
from hercs.wire.served import decode_served_batch, decode_status, status_request
from tests.fault.fuzz.probes import base_episode, make_weights
from tests.fault.fuzz.runs import CYCLES_PER_EPOCH, KR, REQUEST_TIMEOUT_S, RUN_R, SPEC, WAIT_S, K
from tests.fault.fuzz.world import World, check_clusterer

pytestmark = [pytest.mark.integration, pytest.mark.timeout(420)]


BARRAGES = {"replay/insert", "replay/sample", "replay/episode", "replay/clusterer_state",
            "cluster/model", "eval/result (replay)", "replay/inserted", "weights",
            "eval/request", "run/progress", "replay/sample replies (learner)",
            "eval/result (learner)"}


def test_after_the_barrage_every_service_serves_valid_input_and_stops_cleanly(
        world: World) -> None:
    w = world
    w.assert_running()
    w.assert_logs_clean()
    # the replay: a valid insert is acked and stored, a valid sample served
    msg = base_episode(123456, actor="fz-after")
    ack = pb.InsertAck.FromString(w.client.request(KR.insert, msg.SerializeToString(),
                                                   timeout_s=REQUEST_TIMEOUT_S))
    assert not ack.duplicate and ack.episode_id == len(w.ledger.stored)
    w.ledger.stored[ack.episode_id] = msg
    request = pb.SampleRequest(schema_version=SCHEMA_VERSION, run=RUN_R, learner_id="fz",
                               request_id=7, num_minibatches=3, batch_size=32)
    batch = decode_served_batch(w.client.request(KR.sample, request.SerializeToString(),
                                                 timeout_s=REQUEST_TIMEOUT_S),
                                spec=SPEC, k=K, batch_size=32, num_minibatches=3)
    status = decode_status(w.client.request(KR.status_at, status_request(batch.samples_served),
                                            timeout_s=REQUEST_TIMEOUT_S), max_bytes=1 << 16)
    assert status.cluster_model_version == w.model_oracle.version
    w.check_replay_counters()
    check_clusterer(w)
    # the actor: valid weights are still adopted
    again = make_weights(version=4_000_000_003, epoch=4, evaluate=False, seed=8)
    w.weights_pub.put(again.SerializeToString())
    w.ledger.actor_versions.add(again.version)
    versions = w.actor_replay.next_versions(lambda v: v == again.version, "with new weights")
    assert set(versions) <= w.ledger.actor_versions
    # the learner: still training
    w.learner_replay.valid.set()
    deadline = time.monotonic() + WAIT_S
    latest = 0
    while latest < 4 * CYCLES_PER_EPOCH:
        latest = max(latest, int(w.learner_weights.get(
            timeout=max(deadline - time.monotonic(), 0.01)).version))

    for name in ("actor", "evaluator", "learner", "clusterer", "replay"):
        code = w.procs[name].stop()
        assert code == 0, f"{name} exited {code}:\n{w.procs[name].log_text()[-4000:]}"
    w.assert_logs_clean()
    # what the replay logged: the stored episodes, the adopted models, the valid results
    run_dir = Path(w.configs["replay"].run.run_dir) / RUN_R
    logged = dict(read_episode_messages(run_dir))
    assert sorted(logged) == sorted(w.ledger.stored)
    for episode_id, stored in w.ledger.stored.items():
        assert logged[episode_id] == stored, episode_id
    assert [m.version for m in read_cluster_models(run_dir)] == w.ledger.models
    assert list(read_eval_results(run_dir)) == w.ledger.replay_evals

    total = sum(w.ledger.sent.values())
    print(f"payloads sent: {total}; by endpoint: {dict(w.ledger.sent)}; not sent (valid, "
          f"and costly or consequential): {dict(w.ledger.skipped)}; replay rejects: "
          f"{dict(w.ledger.replay_rejects)}; clusterer: {dict(w.ledger.header_rejects)}; "
          f"evaluator rejects: {w.ledger.evaluator_rejects}; bad batches: "
          f"{w.ledger.bad_batches}")
    if set(w.ledger.sent) >= BARRAGES:
        assert total >= 10_000, f"only {total} payloads sent"
