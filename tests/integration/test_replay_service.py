"""The replay service as a real process over real Zenoh: acks, dedup, rejects by reason,
rate-limited sampling, cluster-balanced batches, and acked data surviving a SIGKILL."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.synthetic_episodes import random_episode
from hercs.net.transport import RemoteError, Transport
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.wire.codec import array_to_msg, episode_to_msg
from tests.integration.services import ServiceProcess, make_test_config, next_replay_status

pytestmark = pytest.mark.integration
KEYS = RunKeys("t")
TIMEOUT = 30.0


@pytest.fixture
def replay(tmp_path: Path, endpoint: str, router: Transport, request):
    overrides = getattr(request, "param", [])
    config, path = make_test_config(tmp_path, endpoint, [
        "task.name=push", "run.method=her-cs", "cluster.k=4", "training.minibatches_per_cycle=8",
        "training.episodes_per_cycle=4", "replay.rate_tolerance_updates=16",
        "replay.min_episodes_to_sample=4", *overrides])
    proc = ServiceProcess("replay", path, "replay", tmp_path)
    yield config, proc
    code = proc.stop()
    assert code == 0, proc.log_text()[-3000:]


def insert(client: Transport, msg: pb.Episode) -> pb.InsertAck:
    return pb.InsertAck.FromString(client.request(KEYS.insert, msg.SerializeToString(),
                                                  timeout_s=TIMEOUT))


def episode_msg(spec, seq: int, actor: str = "a0") -> pb.Episode:
    ep = random_episode(spec, np.random.default_rng(seq), actor_id=actor, seq=seq)
    return episode_to_msg(ep, run="t", task=spec.name)


def insert_episodes(client: Transport, spec, seqs: range) -> list[pb.InsertAck]:
    """Inserts actor a0's episodes of these sequence numbers, one after the other."""
    return [insert(client, episode_msg(spec, seq)) for seq in seqs]


def status(client: Transport) -> pb.ReplayStatus:
    return next_replay_status(client, KEYS.status, TIMEOUT)


def status_at(client: Transport, batch: pb.Batch) -> pb.ReplayStatus:
    """The counters when `batch` was drawn, as the learner reads them (`replay/status_at`)."""
    request = pb.ReplayStatusRequest(schema_version=SCHEMA_VERSION, samples=batch.samples_served)
    return pb.ReplayStatus.FromString(client.request(KEYS.status_at, request.SerializeToString(),
                                                     timeout_s=TIMEOUT))


def test_config_is_served_for_remote_actors(replay, open_client) -> None:
    raw = open_client().request(KEYS.config, b"", timeout_s=TIMEOUT)
    assert yaml.safe_load(raw)["run"]["method"] == "her-cs"


def test_acks_dedup_and_rejects(replay, open_client) -> None:
    config, _ = replay
    spec = config.task.spec
    client = open_client()
    acks = insert_episodes(client, spec, range(3))
    assert [a.episode_id for a in acks] == [0, 1, 2] and not any(a.duplicate for a in acks)
    again = insert(client, episode_msg(spec, 1))
    assert again.duplicate and again.episode_id == 1

    bad = episode_msg(spec, 9)
    bad_dims = episode_msg(spec, 10)
    array_to_msg(np.zeros((51, 10), np.float32), out=bad_dims.obs)
    nan = episode_msg(spec, 11)
    values = np.zeros((50, 3), np.float32)
    values[4, 1] = np.nan
    array_to_msg(values, out=nan.g)
    cases = [(b"\xff\xfe garbage", "undecodable"), (bad_dims.SerializeToString(), "bad_shape"),
             (nan.SerializeToString(), "non_finite")]
    for payload, reason in cases:
        with pytest.raises(RemoteError) as err:
            client.request(KEYS.insert, payload, timeout_s=TIMEOUT)
        assert err.value.reason == reason
    assert insert(client, bad).episode_id == 3, "the replay keeps serving after rejects"
    st = status(client)
    assert st.size_episodes == 4 and st.inserts == 4 and st.duplicates == 1
    assert dict(st.rejects) == {"undecodable": 1, "bad_shape": 1, "non_finite": 1}


def sample(client: Transport, n: int, request_id: int = 1) -> pb.Batch:
    req = pb.SampleRequest(schema_version=SCHEMA_VERSION, run="t", learner_id="L",
                           request_id=request_id, num_minibatches=n, batch_size=64)
    return pb.Batch.FromString(client.request(KEYS.sample, req.SerializeToString(),
                                              timeout_s=TIMEOUT))


def test_rate_limiter_holds_samples_until_inserts_arrive(replay, open_client) -> None:
    config, _ = replay
    spec = config.task.spec
    client = open_client()
    insert_episodes(client, spec, range(4))
    # ρ = 8/4 = 2 updates per episode, N_min = 4, E = 16: window for the surplus d = 2I − S
    # is [8 − 16, 8 + 16]. After 4 inserts d = 8: 8 minibatches are admitted (d → 0), the
    # next 8 too (d → −8), the third must wait for inserts.
    assert len(sample(client, 8, 1).minibatches) == 8
    assert len(sample(client, 8, 2).minibatches) == 8
    done = threading.Event()
    result: list[pb.Batch] = []

    def third() -> None:
        result.append(sample(client, 8, 3))
        done.set()

    thread = threading.Thread(target=third, daemon=True)
    thread.start()
    assert not done.wait(1.0), "the third request must be held by the rate limiter"
    assert status(client).rate_limiter == "holding-samples"
    insert_episodes(client, spec, range(4, 8))  # 4 more episodes: d = −8 + 8 = 0 ≥ −8 + 8, admitted
    assert done.wait(TIMEOUT)
    assert result[0].request_id == 3 and status_at(client, result[0]).inserts == 8
    thread.join()
    # the counters of each batch's moment, later, on their own channel
    assert result[0].samples_served == 24 and status_at(client, result[0]).samples == 24
    assert "status" not in {f.name for f in pb.Batch.DESCRIPTOR.fields}, "no counters inside"
    late = status(client)
    assert (late.inserts, late.samples) == (8, 24)


def test_status_at_answers_garbage_with_an_error_and_an_unknown_moment_with_now(
        replay, open_client) -> None:
    config, _ = replay
    client = open_client()
    insert_episodes(client, config.task.spec, range(4))
    first = sample(client, 2, 1)
    with pytest.raises(RemoteError, match="ReplayStatusRequest"):
        client.request(KEYS.status_at, b"\xff\xfe not a message", timeout_s=TIMEOUT)
    unknown = pb.Batch(samples_served=10**6)
    now = status_at(client, unknown)
    assert (now.samples, now.inserts) == (2, 4), "the current counters, which say so"
    assert status_at(client, first).samples == first.samples_served == 2, "still serving"


@pytest.mark.parametrize("replay", [["replay.free_run=true"]], indirect=True, ids=["free-run"])
def test_cluster_model_relabels_and_balances_batches(replay, open_client) -> None:
    config, _ = replay
    spec = config.task.spec
    client = open_client()
    insert_episodes(client, spec, range(40))
    centroids = np.array([[-1, -1, 0], [1, 1, 0], [-1, 1, 0], [1, -1, 0]], np.float32) * 0.5
    model = pb.ClusterModel(schema_version=SCHEMA_VERSION, version=1,
                            centroids=array_to_msg(centroids), fitted_on=8, failures_seen=8)
    pub = client.publisher(KEYS.cluster_model, latest=True)
    pub.put(model.SerializeToString())
    batch = None
    for request_id in range(1, 50):  # until the replay has adopted the model
        batch = sample(client, 8, request_id)
        if status_at(client, batch).cluster_model_version == 1:
            break
    assert batch is not None and status_at(client, batch).cluster_model_version == 1
    draws = np.asarray(batch.cluster_draws)
    assert draws.sum() == 8 * 64
    sizes = np.asarray(status(client).cluster_sizes)
    assert sizes.sum() == 40
    # Each cluster big enough for the normal rule gets its share of 64/4 = 16 per minibatch.
    for c in np.flatnonzero(sizes >= 4):
        assert draws[c] >= 8 * 16


def test_acked_episodes_survive_sigkill(tmp_path: Path, endpoint: str, router: Transport,
                                        open_client) -> None:
    # no learner samples here: the limiter runs free, or it would hold inserts past its window
    config, path = make_test_config(tmp_path, endpoint, ["task.name=reach", "run.method=her",
                                                         "replay.free_run=true"])
    spec = config.task.spec
    client = open_client()
    proc = ServiceProcess("replay", path, "replay", tmp_path)
    acked = [ack.episode_id for ack in insert_episodes(client, spec, range(12))]
    proc.kill()
    proc = ServiceProcess("replay", path, "replay", tmp_path)
    try:
        again = insert(client, episode_msg(spec, 5))
        assert again.duplicate and again.episode_id == 5, "the restarted replay knows seq 5"
        assert insert(client, episode_msg(spec, 12)).episode_id == 12
        st = status(client)
        assert st.size_episodes == len(acked) + 1
    finally:
        assert proc.stop() == 0, proc.log_text()[-3000:]


def test_episode_queryable_serves_stored_episodes_and_rejects_unknown_ids(
        tmp_path: Path, endpoint: str, router: Transport, open_client) -> None:
    # Push episodes have T = 50: a 150-transition buffer holds 3 episodes, so the 4th insert
    # overwrites episode 0.
    config, path = make_test_config(tmp_path, endpoint, [
        "task.name=push", "run.method=her", "replay.buffer_transitions=150"])
    spec = config.task.spec
    proc = ServiceProcess("replay", path, "replay", tmp_path)
    try:
        client = open_client()
        sent = [episode_msg(spec, seq) for seq in range(4)]
        assert [insert(client, msg).episode_id for msg in sent] == [0, 1, 2, 3]

        def get(episode_id: int) -> pb.Episode:
            request = pb.EpisodeRequest(schema_version=SCHEMA_VERSION, episode_id=episode_id)
            return pb.Episode.FromString(client.request(
                KEYS.episode, request.SerializeToString(), timeout_s=TIMEOUT))

        got = get(2)
        assert got == sent[2], "the stored episode comes back as it was inserted"
        for episode_id, why in ((0, "overwritten by newer episodes"), (9, "not inserted yet")):
            with pytest.raises(RemoteError) as err:
                get(episode_id)
            assert err.value.reason == "unknown_episode"
            assert err.value.detail == (f"EpisodeRequest.episode_id {episode_id}: not stored "
                                        f"({why}; the replay holds 3 episodes with ids up to 3)")
        with pytest.raises(RemoteError) as err:
            client.request(KEYS.episode, b"\xff\xfe garbage", timeout_s=TIMEOUT)
        assert err.value.reason == "undecodable"

        assert insert(client, episode_msg(spec, 4)).episode_id == 4, "still serving inserts"
        assert get(4) == episode_msg(spec, 4)
        # a malformed request is a reject; asking for an id the ring no longer holds is not
        assert dict(status(client).rejects) == {"undecodable": 1}
    finally:
        assert proc.stop() == 0, proc.log_text()[-3000:]
