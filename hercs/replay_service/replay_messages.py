"""What the replay reads from and writes to the wire, as pure functions of a message or a
table result: the limits on a request, the checks a message passes before the table sees it,
and the replies and announcements it makes. `replay_shell` calls them; tests drive them."""

from __future__ import annotations

from hercs.config.limits import (  # the config refuses a run that asks for more
    MAX_BATCH_SIZE,
    MAX_MINIBATCHES_PER_REQUEST,
    MAX_ROWS_PER_REQUEST,
)
from hercs.errors import InvalidMessage
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.replay_service.table import SampleCall, Stored
from hercs.replay_service.table_calls import ClustererSnapshot
from hercs.rl.cluster_model import ClusterModel
from hercs.run.runlog import MAX_SEQUENCE
from hercs.wire.codec import array_to_msg, msg_to_cluster_model
from hercs.wire.validation import validate_centroids, validate_eval_result, validate_sample_request


def sample_call(request: pb.SampleRequest, *, run: str) -> SampleCall:
    """The table's call for a valid request (InvalidMessage naming the field otherwise)."""
    validate_sample_request(
        request, run=run, max_minibatches=MAX_MINIBATCHES_PER_REQUEST,
        max_batch_size=MAX_BATCH_SIZE, max_rows=MAX_ROWS_PER_REQUEST)
    return SampleCall(num_minibatches=int(request.num_minibatches),
                      batch_size=int(request.batch_size),
                      weights_version=int(request.weights_version),
                      request_id=int(request.request_id),
                      samples_kept=int(request.samples_kept),
                      learner_incarnation=str(request.learner_incarnation))


def inserted_header(stored: Stored) -> pb.EpisodeHeader:
    """What `replay/inserted` announces of a newly stored episode (the clusterer, the live
    view and `hercs up` read it)."""
    episode = stored.episode
    return pb.EpisodeHeader(
        schema_version=SCHEMA_VERSION, episode_id=stored.episode_id,
        actor_id=episode.actor_id, seq=episode.seq, success=episode.success,
        final_achieved_goal=array_to_msg(episode.ag[-1]),
        desired_goal=array_to_msg(episode.g[-1]), energy=stored.energy,
        cluster=stored.cluster, policy_version=episode.policy_version)


def insert_ack(stored: Stored) -> pb.InsertAck:
    episode = stored.episode
    return pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id=episode.actor_id,
                        seq=episode.seq, episode_id=stored.episode_id,
                        duplicate=stored.duplicate,
                        next_policy_version=stored.next_policy_version)


def unknown_episode(episode_id: int, first: int, end: int) -> InvalidMessage:
    """The error for an `EpisodeRequest` of an id the replay does not hold (it holds
    ids first..end-1)."""
    why = "not inserted yet" if episode_id >= end else "overwritten by newer episodes"
    held = f"{end - first} episodes with ids up to {end - 1}" if end > first else "no episode yet"
    return InvalidMessage(
        Reason.UNKNOWN_EPISODE,
        f"EpisodeRequest.episode_id {episode_id}: not stored ({why}; the replay holds {held})")


def cluster_model(msg: pb.ClusterModel, *, k: int, goal_dim: int) -> ClusterModel:
    """A checked cluster model: k centroids of the goal's size, a version the log can hold."""
    validate_centroids(msg, k=k, goal_dim=goal_dim)
    _check_loggable("ClusterModel.version", msg.version)  # before adopting it
    return msg_to_cluster_model(msg)


def check_eval_result(msg: pb.EvalResult) -> None:
    validate_eval_result(msg)
    _check_loggable("EvalResult.epoch", msg.epoch)


def _check_loggable(field: str, value: int) -> None:
    """A sequence number the episode log can hold (it is logged with the message)."""
    if value > MAX_SEQUENCE:
        raise InvalidMessage(Reason.BAD_VALUE, f"{field} {value} is above {MAX_SEQUENCE}, "
                             "the largest the episode log holds")


def clusterer_state(snap: ClustererSnapshot) -> pb.ClustererState:
    """What a (re)started clusterer continues from."""
    return pb.ClustererState(
        schema_version=SCHEMA_VERSION, failed_goals=array_to_msg(snap.failed_goals),
        failures_seen=snap.failures_seen, episodes_seen=snap.episodes_seen,
        model_version=snap.model_version)
