"""The one `ClusterModel` codec: what the clusterer publishes is what every reader gets back,
and an episode log written before field 5 was renamed (`failed_goals_seen` → `failures_seen`)
still opens in the readers (`hercs view`, the benches) with the same value."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from bench.synthetic_episodes import random_episode
from hercs.apps.views.view import read_run_log
from hercs.clusterer.clusterer_core import Clusterer
from hercs.config import ClusterConfig
from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.proto.schema import SCHEMA_VERSION
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.task_registry import task_spec
from hercs.run.rundir import RunDir
from hercs.run.runlog import EpisodeLogWriter, read_cluster_models
from hercs.wire.codec import (
    array_to_msg,
    cluster_model_to_msg,
    episode_to_msg,
    msg_to_cluster_model,
)

SPEC = task_spec("push")
CENTROIDS = np.random.default_rng(3).uniform(-1, 1, (8, 3)).astype(np.float32)


def old_cluster_model_class() -> type:
    """`ClusterModel` as the schema declared it before the rename (field 5
    `failed_goals_seen`), in a pool of its own, so that a log written with it embeds that old
    schema exactly as an old run's log does."""
    file_proto = descriptor_pb2.FileDescriptorProto()
    pb.DESCRIPTOR.CopyToProto(file_proto)
    [message] = [m for m in file_proto.message_type if m.name == "ClusterModel"]
    [field] = [f for f in message.field if f.number == 5]
    field.name = "failed_goals_seen"
    field.json_name = "failedGoalsSeen"
    pool = descriptor_pool.DescriptorPool()
    pool.Add(file_proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("hercs.ClusterModel"))


def test_round_trip_keeps_every_field() -> None:
    model = ClusterModel(version=4, centroids=CENTROIDS, n_goals=150, failures_seen=612)
    back = msg_to_cluster_model(pb.ClusterModel.FromString(
        cluster_model_to_msg(model).SerializeToString()))
    assert (back.version, back.n_goals, back.failures_seen) == (4, 150, 612)
    np.testing.assert_array_equal(back.centroids, CENTROIDS)
    assert cluster_model_to_msg(model).schema_version == SCHEMA_VERSION


@pytest.mark.parametrize(("version", "centroids"), [
    (0, CENTROIDS),
    (1, np.full((8, 3), np.nan, np.float32)),
], ids=["version-0", "nan-centroids"])
def test_unusable_model_is_an_invalid_message(version: int, centroids: np.ndarray) -> None:
    msg = pb.ClusterModel(schema_version=SCHEMA_VERSION, version=version,
                          centroids=array_to_msg(centroids), fitted_on=1, failures_seen=1)
    with pytest.raises(InvalidMessage) as err:
        msg_to_cluster_model(msg)
    assert err.value.reason == "bad_value"


def test_clusterer_sets_the_failure_count_it_fitted_at() -> None:
    """`failures_seen` is the failure count (the lockstep gate's fit point), not the episodes
    observed: successes in between do not move it."""
    core = Clusterer(config=ClusterConfig(k=2, fgb_size=4, kmeans_n_init=1), seed=0,
                     goal_dim=SPEC.goal_dim, is_success=SPEC.is_success)
    goal, far = np.zeros(3), np.full(3, 1.0)
    models = []
    for i in range(8):
        assert core.observe(final_ag=goal, desired_goal=goal) is None  # a success
        models.append(core.observe(final_ag=far, desired_goal=goal + 0.01 * i))
    assert (core.episodes_seen, core.failures_seen) == (16, 8)
    fits = [(m.version, m.failures_seen) for m in models if m is not None]
    assert fits == [(1, 4), (2, 8)]  # a refit per fgb_size new failures
    assert [cluster_model_to_msg(m).failures_seen for m in models if m is not None] == [4, 8]


def test_log_written_with_the_old_field_name_still_opens(tmp_path: Path) -> None:
    old_cls = old_cluster_model_class()
    old = old_cls(schema_version=SCHEMA_VERSION, version=3, fitted_on=150,
                  failed_goals_seen=450)
    old.centroids.ParseFromString(array_to_msg(CENTROIDS).SerializeToString())
    rng = np.random.default_rng(0)
    path = RunDir(tmp_path).episode_log
    with EpisodeLogWriter(path, run="old", task="push") as writer:
        writer.append_episode(episode_to_msg(random_episode(SPEC, rng, seq=0), run="old",
                                             task="push"), episode_id=0)
        writer.append_cluster_model(old)
        writer.append_episode(episode_to_msg(random_episode(SPEC, rng, seq=1), run="old",
                                             task="push"), episode_id=1)

    with open(path, "rb") as f:  # the log really holds the old schema
        schemas = make_reader(f).get_summary().schemas.values()
    [schema] = [s for s in schemas if s.name == "hercs.ClusterModel"]
    [old_file] = descriptor_pb2.FileDescriptorSet.FromString(schema.data).file
    [logged] = [m for m in old_file.message_type if m.name == "ClusterModel"]
    assert [f.name for f in logged.field if f.number == 5] == ["failed_goals_seen"]

    [msg] = read_cluster_models(path)
    model = msg_to_cluster_model(msg)
    assert (model.version, model.n_goals, model.failures_seen) == (3, 150, 450)
    np.testing.assert_array_equal(model.centroids, CENTROIDS)
    run = read_run_log(path)
    assert [(m.at_episode, m.model.failures_seen) for m in run.models] == [(1, 450)]
    assert [e.episode_id for e in run.episodes] == [0, 1]
