"""`hercs clusterer` as a real process against a router on loopback.

The test plays the replay: it publishes `EpisodeHeader`s on `replay/inserted` and listens to
`cluster/model`. No sleeps stand in for synchronisation: every wait is on a queue with a
timeout, a publisher's subscriber matching, or the process exit.
"""

from __future__ import annotations

import queue
import subprocess
from pathlib import Path

import numpy as np
import pytest

from hercs.clusterer.clusterer_core import Clusterer
from hercs.config import HercsConfig, apply_overrides
from hercs.net.transport import Transport
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.wire.codec import array_to_msg, msg_to_array
from tests.integration.services import WAIT_S, OpenClient, OpenRunSide, start_service, wait_for

pytestmark = pytest.mark.integration



# ---- the clusterer


def tiny_config(endpoint: str) -> HercsConfig:
    return apply_overrides(HercsConfig(), [
        "run.name=t-clusterer", "run.method=her-cs", "task.name=push", "cluster.fgb_size=16",
        "cluster.k=4", "cluster.kmeans_n_init=3", f"transport.connect=[{endpoint}]",
    ])


def header(ag: np.ndarray, g: np.ndarray, *, seq: int) -> bytes:
    return pb.EpisodeHeader(
        schema_version=SCHEMA_VERSION, episode_id=seq, actor_id="a", seq=seq,
        success=bool(np.linalg.norm(ag - g) < 0.05),
        final_achieved_goal=array_to_msg(np.asarray(ag, np.float32)),
        desired_goal=array_to_msg(np.asarray(g, np.float32)), cluster=-1,
    ).SerializeToString()


def serve_state(replay: Transport, keys: RunKeys, *, goals: np.ndarray | None = None,
                failures: int = 0, episodes: int = 0, model_version: int = 0) -> list[bytes]:
    """Answer `replay/clusterer_state` as the replay does; returns the requests received."""
    requests: list[bytes] = []
    goals = np.zeros((0, 3), np.float32) if goals is None else goals.astype(np.float32)

    def answer(payload: bytes) -> bytes:
        requests.append(payload)
        return pb.ClustererState(schema_version=SCHEMA_VERSION, failed_goals=array_to_msg(goals),
                                 failures_seen=failures, episodes_seen=episodes,
                                 model_version=model_version).SerializeToString()

    replay.serve(keys.clusterer_state, answer)
    return requests


def test_clusterer_fits_after_fgb_size_failures_and_serves_late_joiners(
    open_client: OpenClient, run_side: OpenRunSide, endpoint: str,
) -> None:
    config = tiny_config(endpoint)
    run = run_side(config.run.name)
    replay, keys = run.transport, run.keys
    models: queue.Queue[pb.ClusterModel] = queue.Queue()
    replay.subscribe(keys.cluster_model,
                     lambda key, raw: models.put(pb.ClusterModel.FromString(raw)), latest=True)
    metrics = run.metrics("clusterer")
    inserted = replay.publisher(keys.inserted, block=True)
    serve_state(replay, keys)  # a fresh run: nothing to continue

    clusterer = run.start("clusterer", config, "c0")
    assert inserted.wait_for_subscribers(WAIT_S), "the clusterer never subscribed"

    rng = np.random.default_rng(0)
    expected = Clusterer(config=config.cluster, seed=config.run.seed,
                         goal_dim=config.task.spec.goal_dim,
                         is_success=config.task.spec.is_success)
    expected_model = None

    def publish(ag: np.ndarray, g: np.ndarray, seq: int) -> None:
        nonlocal expected_model
        inserted.put(header(ag, g, seq=seq))
        model = expected.observe(final_ag=ag.astype(np.float32), desired_goal=g.astype(np.float32))
        expected_model = expected_model or model

    inserted.put(b"\x08\x01garbage that is not a header")
    bad = pb.EpisodeHeader.FromString(header(np.zeros(3), np.ones(3), seq=99))
    bad.desired_goal.CopyFrom(array_to_msg(np.array([0.0, np.nan, 0.0], np.float32)))
    inserted.put(bad.SerializeToString())
    bad.desired_goal.CopyFrom(array_to_msg(np.zeros(2, np.float32)))
    inserted.put(bad.SerializeToString())
    failures = 0
    for seq in range(40):
        g = rng.uniform(-1, 1, 3)
        if seq % 3 == 0:  # a success: never a failed goal
            publish(g + 0.01, g, seq)
        else:
            publish(g + rng.uniform(0.2, 0.5, 3), g, seq)
            failures += 1
        if failures == config.cluster.fgb_size:
            break
    assert expected_model is not None and expected.failures_seen == config.cluster.fgb_size
    for seq in range(100, 103):  # more failures after the fit: no second model yet
        g = rng.uniform(-1, 1, 3)
        publish(g + 1.0, g, seq)

    got = models.get(timeout=WAIT_S)
    assert (got.version, got.fitted_on) == (1, config.cluster.fgb_size)
    assert got.failures_seen == config.cluster.fgb_size, "fitted exactly at the 16th failure"
    centroids = msg_to_array(got.centroids)
    assert centroids.shape == (config.cluster.k, 3) and centroids.dtype == np.float32
    np.testing.assert_allclose(centroids, expected_model.centroids, rtol=0, atol=1e-6)

    late: queue.Queue[pb.ClusterModel] = queue.Queue()
    open_client().subscribe(keys.cluster_model,
                            lambda key, raw: late.put(pb.ClusterModel.FromString(raw)), latest=True)
    assert late.get(timeout=WAIT_S).version == 1

    # the garbage, the NaN and the misshapen header were skipped; the service kept counting
    values = wait_for(metrics, lambda m: m["failed_goals_seen"] == expected.failures_seen,
                      "metrics counting every valid failure")
    assert values["rejected"] == 3
    assert values["episodes_seen"] == expected.episodes_seen
    assert values["model_version"] == 1 and values["refits"] == 1
    assert models.empty()

    run.stop_cleanly(clusterer, "clusterer", "c0")


def test_a_restarted_clusterer_continues_the_runs_buffer_counts_and_versions(
    open_client: OpenClient, endpoint: str, tmp_path: Path, procs: list[subprocess.Popen],
) -> None:
    """The replay's snapshot says: 60 episodes, 40 failures, model v7 in use, and the newest
    16 failed goals. The restarted clusterer refills its buffer with them, skips headers the
    snapshot counted, and its first model, 16 new failures later, is v8."""
    config = tiny_config(endpoint)
    keys = RunKeys(config.run.name)
    replay = open_client()
    models: queue.Queue[pb.ClusterModel] = queue.Queue()
    replay.subscribe(keys.cluster_model,
                     lambda key, raw: models.put(pb.ClusterModel.FromString(raw)), latest=True)
    inserted = replay.publisher(keys.inserted, block=True)
    rng = np.random.default_rng(1)
    old_goals = rng.uniform(-1, 1, (16, 3))
    requests = serve_state(replay, keys, goals=old_goals, failures=40, episodes=60,
                           model_version=7)
    procs.append(start_service("clusterer", config, "c1", tmp_path))
    assert inserted.wait_for_subscribers(WAIT_S)
    for episode_id in range(50, 60):  # already in the snapshot: not counted again
        g = rng.uniform(-1, 1, 3)
        inserted.put(header(g + 1.0, g, seq=episode_id))
    expected = Clusterer(config=config.cluster, seed=config.run.seed,
                         goal_dim=config.task.spec.goal_dim,
                         is_success=config.task.spec.is_success)
    expected.resume(failed_goals=old_goals, failures_seen=40, episodes_seen=60, model_version=7)
    model = None
    for episode_id in range(60, 76):
        g = rng.uniform(-1, 1, 3)
        inserted.put(header(g + 1.0, g, seq=episode_id))
        model = expected.observe(final_ag=(g + 1.0).astype(np.float32),
                                 desired_goal=g.astype(np.float32)) or model
    got = models.get(timeout=WAIT_S)
    assert requests, "it asked the replay where the run stands"
    assert model is not None and (got.version, model.version) == (8, 8)
    assert (got.fitted_on, got.failures_seen) == (16, 56)
    np.testing.assert_allclose(msg_to_array(got.centroids), model.centroids, rtol=0, atol=1e-6)
    assert models.empty()
