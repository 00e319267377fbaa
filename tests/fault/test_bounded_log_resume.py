"""A replay with a small bounded episode log, SIGKILLed right after the ack of the episode that
fills a segment, resumes the buffer it would have without the bound: the same episodes under
the same ids, retries still deduplicated, the log under its bound plus one segment once pruned.
Real `hercs replay`, Zenoh and MCAP; Reach, 20-episode buffer, 5-episode segments. (The exact
comparison with a log kept whole: tests/unit/replay_service/test_bounded_log.py.)"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.net.transport import RemoteError, Transport
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.run.runlog import read_episode_messages, segment_paths
from hercs.wire.codec import episode_to_msg
from tests.integration.services import ServiceProcess, make_test_config, next_replay_status
from tests.support import free_endpoint

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]

KEYS = RunKeys("t")
TIMEOUT_S = 30.0
CAPACITY = 20
MAX_BYTES = 400_000
"""About 1.7 buffers of Reach episodes with their scenes: more than resume needs (1.5)."""
KILL_AFTER = 65
"""Killed after the ack of episode 64, the one that fills the 13th segment."""
EPISODES = 90


@pytest.fixture
def client() -> Iterator[tuple[str, Transport]]:
    endpoint = free_endpoint()
    router = Transport.open(mode="router", listen=[endpoint])
    transport = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=5.0)
    yield endpoint, transport
    transport.close()
    router.close()


def insert(client: Transport, msg: pb.Episode) -> pb.InsertAck:
    return pb.InsertAck.FromString(client.request(KEYS.insert, msg.SerializeToString(),
                                                  timeout_s=TIMEOUT_S))


def stored(client: Transport, episode_id: int) -> pb.Episode | str:
    """The replay's stored episode `episode_id`, or the reason it has none."""
    request = pb.EpisodeRequest(schema_version=SCHEMA_VERSION, episode_id=episode_id)
    try:
        return pb.Episode.FromString(client.request(KEYS.episode, request.SerializeToString(),
                                                    timeout_s=TIMEOUT_S))
    except RemoteError as exc:
        return exc.detail


def log_bytes(run_dir: Path) -> int:
    """The log's size now; a segment the replay deletes meanwhile counts 0."""
    total = 0
    for path in segment_paths(run_dir):
        with contextlib.suppress(FileNotFoundError):
            total += path.stat().st_size
    return total


def status(client: Transport) -> pb.ReplayStatus:
    return next_replay_status(client, KEYS.status, TIMEOUT_S)


def test_a_killed_replay_resumes_the_same_buffer_from_a_bounded_log(
        tmp_path: Path, client: tuple[str, Transport]) -> None:
    endpoint, transport = client
    config, path = make_test_config(tmp_path, endpoint, [
        "task.name=reach", "run.method=her", "replay.free_run=true",
        "training.max_policy_lag=-1", f"replay.buffer_transitions={CAPACITY * 50}",
        f"replay.log_max_bytes={MAX_BYTES}"])
    spec = config.task.spec
    run_dir = tmp_path / "runs" / "t"
    sent = [episode_to_msg(random_episode(spec, np.random.default_rng(seq), actor_id="a",
                                          seq=seq), run="t", task=spec.name)
            for seq in range(EPISODES)]
    sizes = []
    proc = ServiceProcess("replay", path, "replay", tmp_path)
    try:
        for seq in range(KILL_AFTER):
            assert insert(transport, sent[seq]).episode_id == seq
            sizes.append(log_bytes(run_dir))
    finally:
        proc.kill()

    proc = ServiceProcess("replay", path, "replay", tmp_path)
    try:
        again = insert(transport, sent[KILL_AFTER - 3])
        assert again.duplicate and again.episode_id == KILL_AFTER - 3, "retries still dedup'd"
        st = status(transport)
        assert (st.size_episodes, st.inserts) == (CAPACITY, KILL_AFTER)
        oldest = KILL_AFTER - CAPACITY
        assert all(stored(transport, i) == sent[i] for i in range(oldest, KILL_AFTER)), \
            "the buffer holds the last 20 episodes as they were sent"
        assert "overwritten by newer episodes" in str(stored(transport, oldest - 1))
        for seq in range(KILL_AFTER, EPISODES):
            assert insert(transport, sent[seq]).episode_id == seq
            sizes.append(log_bytes(run_dir))
    finally:
        assert proc.stop() == 0, proc.log_text()[-3000:]
    log_text = proc.log_text()
    assert "started from the replay state the episode log saved at episode" in log_text
    closed = segment_paths(run_dir)[:-1]
    slack = max(p.stat().st_size for p in closed)  # one segment, the largest kept
    # an ack may come before the background pruning, and after the restart the resumed
    # segment and the new live one both wait for the first new state: one more segment
    assert max(sizes) <= MAX_BYTES + 2 * slack, (max(sizes), slack)
    assert sizes[-1] <= MAX_BYTES + slack, (sizes[-1], slack)
    ids = [i for i, _ in read_episode_messages(run_dir)]
    assert ids == list(range(ids[0], EPISODES)) and 0 < ids[0] <= EPISODES - CAPACITY, \
        "old segments went; every buffered episode stayed, ids contiguous"
