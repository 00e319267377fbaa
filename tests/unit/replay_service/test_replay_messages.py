"""The replay's wire decisions without Zenoh (hercs/replay_service/replay_messages.py): what
a request becomes, which messages are refused and why, what an insert is answered."""

from __future__ import annotations

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.errors import InvalidMessage
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.replay_messages import (
    MAX_ROWS_PER_REQUEST,
    cluster_model,
    insert_ack,
    inserted_header,
    sample_call,
    unknown_episode,
)
from hercs.replay_service.table import Stored
from hercs.rl.task_registry import task_spec
from hercs.run.runlog import MAX_SEQUENCE
from hercs.wire.codec import array_to_msg, msg_to_array

SPEC = task_spec("push")


def _request(**fields: object) -> pb.SampleRequest:
    values = dict(schema_version=SCHEMA_VERSION, run="r", num_minibatches=40, batch_size=256,
                  weights_version=3, request_id=9, samples_kept=120, learner_incarnation="L1")
    values.update(fields)
    return pb.SampleRequest(**values)  # type: ignore[arg-type]


def test_a_sample_request_becomes_the_tables_call() -> None:
    call = sample_call(_request(), run="r")
    assert (call.num_minibatches, call.batch_size, call.weights_version, call.request_id,
            call.samples_kept, call.learner_incarnation) == (40, 256, 3, 9, 120, "L1")


@pytest.mark.parametrize(("fields", "match"), [
    ({"run": "other"}, "run"),
    ({"num_minibatches": 400, "batch_size": 8192}, str(MAX_ROWS_PER_REQUEST)),
    ({"batch_size": 0}, "batch_size"),
])
def test_a_request_out_of_bounds_is_refused_naming_the_field(fields: dict, match: str) -> None:
    with pytest.raises(InvalidMessage, match=match):
        sample_call(_request(**fields), run="r")


def test_an_insert_is_acked_and_announced_with_what_the_table_stored() -> None:
    episode = random_episode(SPEC, np.random.default_rng(0), actor_id="a-1", seq=7)
    stored = Stored(episode=episode, episode_id=41, duplicate=False, energy=0.5, cluster=2,
                    next_policy_version=4)
    ack = insert_ack(stored)
    assert (ack.actor_id, ack.seq, ack.episode_id, ack.duplicate,
            ack.next_policy_version) == ("a-1", 7, 41, False, 4)
    header = inserted_header(stored)
    assert (header.episode_id, header.cluster, header.energy) == (41, 2, 0.5)
    np.testing.assert_array_equal(msg_to_array(header.final_achieved_goal), episode.ag[-1])
    np.testing.assert_array_equal(msg_to_array(header.desired_goal), episode.g[-1])


def test_an_unknown_episode_says_whether_it_is_to_come_or_gone() -> None:
    assert "not inserted yet" in str(unknown_episode(12, 0, 10))
    gone = unknown_episode(2, 5, 10)
    assert gone.reason == Reason.UNKNOWN_EPISODE
    assert "overwritten" in str(gone) and "5 episodes with ids up to 9" in str(gone)
    assert "no episode yet" in str(unknown_episode(0, 0, 0))


def test_a_cluster_model_the_log_could_not_hold_is_refused() -> None:
    msg = pb.ClusterModel(schema_version=SCHEMA_VERSION, version=MAX_SEQUENCE + 1,
                          centroids=array_to_msg(np.zeros((8, 3), np.float32)))
    with pytest.raises(InvalidMessage, match="above"):
        cluster_model(msg, k=8, goal_dim=3)
    msg.version = 5
    assert cluster_model(msg, k=8, goal_dim=3).version == 5
    with pytest.raises(InvalidMessage):
        cluster_model(msg, k=4, goal_dim=3)
