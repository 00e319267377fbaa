"""Hostile input to the replay's queryables: insert, sample, episode, clusterer state."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.wire.codec import episode_to_msg, msg_to_array, msg_to_episode
from hercs.wire.served import decode_served_batch, decode_status, status_request
from tests.fault.fuzz.oracles import insert_verdict, parse_verdict, sample_verdict
from tests.fault.fuzz.probes import (
    BASE_EPISODES,
    OTHER_MESSAGES,
    Probe,
    run_barrage,
    unknown_field,
)
from tests.fault.fuzz.runs import (
    KR,
    MAX_BYTES,
    MAX_VALID_SAMPLE_ROWS,
    REQUEST_TIMEOUT_S,
    RUN_R,
    SPEC,
    VALID,
    K,
)
from tests.fault.fuzz.strategies import (
    clusterer_state_probes,
    episode_probes,
    episode_request_probes,
    sample_request_probes,
)
from tests.fault.fuzz.world import World, asked_valid, checked_verdicts, sent

pytestmark = [pytest.mark.integration, pytest.mark.timeout(420)]


def refused_for_the_replays_state(msg: pb.Episode, reason: str) -> bool:
    """A well-formed episode the wire admits and the replay may still refuse for what it
    has seen (issue 57), which the oracle, a pure decoder, cannot know: acted with a weights
    version past any the learner can have published (`future_policy`: the fuzz's sample
    requests announce versions; never one of 1 or below), or holding a value a thousand std
    past the statistics once they are warm (`implausible`: the extreme probes' ±3.4e38)."""
    if reason == "future_policy":
        return msg.policy_version > 1
    if reason == "implausible":
        arrays = (msg_to_array(a) for a in (msg.obs, msg.ag, msg.g))
        return any(bool(np.any(np.abs(a.astype(np.float64)) >= 1e30)) for a in arrays)
    return False


@pytest.mark.full
def test_replay_insert_rejects_bad_episodes_and_stores_only_valid_ones(world: World) -> None:
    w = world
    bases = [m.SerializeToString() for m in BASE_EPISODES]

    def barrage(probes: list[Probe]) -> None:
        verdicts = checked_verdicts(probes, insert_verdict)
        known = dict(w.ledger.keys)
        new: dict[tuple[str, int], list[tuple[pb.InsertAck, pb.Episode]]] = {}
        for probe, reply, reason, detail in asked_valid(w, KR.insert, probes, verdicts):
            msg = pb.Episode.FromString(probe.payload)
            if reply is None and refused_for_the_replays_state(msg, reason):
                w.ledger.replay_rejects[reason] += 1  # counted by the replay as well
                continue
            assert reply is not None, (probe, reason, detail)
            ack = pb.InsertAck.FromString(reply)
            assert (ack.actor_id, ack.seq) == (msg.actor_id, msg.seq), probe
            key = (msg.actor_id, msg.seq)
            if key in known:
                assert ack.duplicate and ack.episode_id == known[key], probe
                w.ledger.duplicates += 1
            else:
                new.setdefault(key, []).append((ack, msg))
        for key, acks in new.items():  # of concurrent inserts of one new pair, one stores it
            firsts = [(ack, msg) for ack, msg in acks if not ack.duplicate]
            assert len(firsts) == 1, (key, [a for a, _ in acks])
            episode_id = firsts[0][0].episode_id
            assert all(ack.episode_id == episode_id for ack, _ in acks)
            assert episode_id not in w.ledger.stored
            w.ledger.stored[episode_id] = firsts[0][1]
            w.ledger.keys[key] = episode_id
            w.ledger.duplicates += len(acks) - 1
        sent(w, "replay/insert", probes)

    run_barrage(barrage, episode_probes(), bases, MAX_BYTES, examples=135)
    assert sorted(w.ledger.stored) == list(range(len(w.ledger.stored))), "ids are dense"
    w.check_replay_counters()


def test_replay_sample_rejects_bad_requests_and_serves_valid_ones(world: World) -> None:
    w = world
    bases = [p for name, p in OTHER_MESSAGES if name == "SampleRequest"]

    def barrage(probes: list[Probe]) -> None:
        verdicts = checked_verdicts(probes, sample_verdict)
        keep = []
        for probe, verdict in zip(probes, verdicts, strict=True):
            if verdict == VALID:
                msg = pb.SampleRequest.FromString(probe.payload)
                if msg.num_minibatches * msg.batch_size > MAX_VALID_SAMPLE_ROWS:
                    w.ledger.skipped["replay/sample (valid, large)"] += 1
                    continue
            keep.append((probe, verdict))
        for probe, reply, reason, detail in asked_valid(
                w, KR.sample, [p for p, _ in keep], [v for _, v in keep]):
            assert reply is not None, (probe, reason, detail)
            msg = pb.SampleRequest.FromString(probe.payload)
            batch = decode_served_batch(reply, spec=SPEC, k=K, batch_size=msg.batch_size,
                                        num_minibatches=msg.num_minibatches)
            assert pb.Batch.FromString(reply).request_id == msg.request_id
            assert int(batch.cluster_draws.sum()) == msg.num_minibatches * msg.batch_size
            status = decode_status(w.client.request(KR.status_at, status_request(
                batch.samples_served), timeout_s=REQUEST_TIMEOUT_S), max_bytes=1 << 16)
            assert status.cluster_model_version == w.model_oracle.version
        sent(w, "replay/sample", [p for p, _ in keep])

    run_barrage(barrage, sample_request_probes(), bases, MAX_BYTES, examples=65)
    w.check_replay_counters()


def test_replay_episode_queryable_serves_stored_episodes_only(world: World) -> None:
    w = world
    bases = [pb.EpisodeRequest(schema_version=SCHEMA_VERSION, episode_id=i).SerializeToString()
             for i in (0, 3, 200)]
    verdict_of = parse_verdict(pb.EpisodeRequest, MAX_BYTES)

    def barrage(probes: list[Probe]) -> None:
        verdicts = checked_verdicts(probes, verdict_of)
        for probe, reply, reason, detail in asked_valid(w, KR.episode, probes, verdicts):
            episode_id = pb.EpisodeRequest.FromString(probe.payload).episode_id
            stored = w.ledger.stored.get(episode_id)
            if stored is None:  # a miss: an error reply, not a reject
                assert (reply, reason) == (None, "unknown_episode") and detail, (probe, reason)
                continue
            assert reply is not None, (probe, reason, detail)
            expected = episode_to_msg(msg_to_episode(stored), run=RUN_R, task=SPEC.name)
            assert pb.Episode.FromString(reply) == expected, probe
        sent(w, "replay/episode", probes)

    run_barrage(barrage, episode_request_probes(), bases, MAX_BYTES, examples=60)
    w.check_replay_counters()


def test_replay_clusterer_state_queryable(world: World) -> None:
    w = world
    bases = [pb.ClustererStateRequest(schema_version=SCHEMA_VERSION).SerializeToString()
             + unknown_field(8)]
    verdict_of = parse_verdict(pb.ClustererStateRequest, MAX_BYTES)

    def barrage(probes: list[Probe]) -> None:
        verdicts = checked_verdicts(probes, verdict_of)
        for probe, reply, reason, detail in asked_valid(w, KR.clusterer_state, probes, verdicts):
            assert reply is not None, (probe, reason, detail)
            state = pb.ClustererState.FromString(reply)
            goals = msg_to_array(state.failed_goals)
            assert goals.ndim == 2 and goals.shape[1] == 3 and np.isfinite(goals).all()
            assert state.episodes_seen == len(w.ledger.stored)
            assert state.model_version == w.model_oracle.version
        sent(w, "replay/clusterer_state", probes)

    run_barrage(barrage, clusterer_state_probes(), bases, MAX_BYTES, examples=40)
    w.check_replay_counters()
