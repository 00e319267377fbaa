"""`hercs clusterer` as a real process against a router on loopback.

The test plays the replay: it publishes `EpisodeHeader`s on `replay/inserted` and listens to
`cluster/model`. No sleeps stand in for synchronisation: every wait is on a queue with a
timeout, a publisher's subscriber matching, or the process exit.
"""

from __future__ import annotations

import queue
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from clusterer.core import Clusterer
from hercs.codec import array_to_msg, msg_to_array
from hercs.config import HercsConfig, apply_overrides
from hercs.transport import Transport
from proto import SCHEMA_VERSION
from proto import hercs_pb2 as pb
from proto.keys import RunKeys
from tests.integration.services import (
    WAIT_S,
    sigterm_exits_cleanly,
    start_service,
    wait_for,
)

pytestmark = pytest.mark.integration


OpenClient = Callable[[], Transport]


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


def test_clusterer_fits_after_fgb_size_failures_and_serves_late_joiners(
    open_client: OpenClient, endpoint: str, tmp_path: Path, procs: list[subprocess.Popen],
) -> None:
    config = tiny_config(endpoint)
    keys = RunKeys(config.run.name)
    replay = open_client()
    alive: queue.Queue = queue.Queue()
    replay.watch_alive(keys.all_alive, lambda key, up: alive.put((key, up)))
    models: queue.Queue[pb.ClusterModel] = queue.Queue()
    replay.subscribe(keys.cluster_model,
                     lambda key, raw: models.put(pb.ClusterModel.FromString(raw)), latest=True)
    metrics: queue.Queue[dict[str, float]] = queue.Queue()
    replay.subscribe(keys.metrics("clusterer"),
                     lambda key, raw: metrics.put(dict(pb.Metrics.FromString(raw).values)))
    inserted = replay.publisher(keys.inserted, block=True)

    procs.append(start_service("clusterer", config, "c0", tmp_path))
    wait_for(alive, lambda c: c == (keys.alive("clusterer", "c0"), True), "the clusterer")
    assert inserted.wait_for_subscribers(WAIT_S), "the clusterer never subscribed"

    rng = np.random.default_rng(0)
    expected = Clusterer(config=config.cluster, seed=config.run.seed, spec=config.task.spec)
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
    assert got.failed_goals_seen == config.cluster.fgb_size, "fitted exactly at the 16th failure"
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
    assert values["episodes_seen"] == expected.inserts_seen
    assert values["model_version"] == 1 and values["refits"] == 1
    assert models.empty()

    sigterm_exits_cleanly(procs[0], alive, keys.alive("clusterer", "c0"))
