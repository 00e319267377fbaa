"""Oracles: each payload's fate, predicted by the decoders the service itself runs on it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from hercs.actors.builder import ActorBuilder
from hercs.clusterer.clusterer_shell import decode_header
from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.replay_messages import (
    MAX_BATCH_SIZE,
    MAX_MINIBATCHES_PER_REQUEST,
    MAX_ROWS_PER_REQUEST,
)
from hercs.rl.cluster_model import ClusterModel
from hercs.run.runlog import MAX_SEQUENCE
from hercs.wire.codec import msg_to_array
from hercs.wire.served import decode_served_batch
from hercs.wire.validation import (
    decode_episode,
    parse_message,
    validate_centroids,
    validate_eval_result,
    validate_sample_request,
)
from tests.fault.fuzz.runs import (
    ACTOR_CONFIG,
    LEARNER_B,
    LEARNER_EVAL_MAX_BYTES,
    LEARNER_N,
    MAX_BYTES,
    RUN_R,
    SPEC,
    VALID,
    K,
)


def reason_of(decode: Callable[[], object]) -> str:
    try:
        decode()
    except InvalidMessage as exc:
        return str(exc.reason)
    return VALID


def insert_verdict(raw: bytes) -> str:
    return reason_of(lambda: decode_episode(raw, SPEC, run=RUN_R, max_bytes=MAX_BYTES))


def sample_verdict(raw: bytes) -> str:
    def check() -> None:
        msg = parse_message(raw, pb.SampleRequest, max_bytes=MAX_BYTES)
        validate_sample_request(msg, run=RUN_R,
                                            max_minibatches=MAX_MINIBATCHES_PER_REQUEST,
                                            max_batch_size=MAX_BATCH_SIZE,
                                            max_rows=MAX_ROWS_PER_REQUEST)

    return reason_of(check)


def parse_verdict(cls: type[Any], limit: int) -> Callable[[bytes], str]:
    return lambda raw: reason_of(lambda: parse_message(raw, cls, max_bytes=limit))


def eval_verdict(raw: bytes, *, limit: int = LEARNER_EVAL_MAX_BYTES) -> str:
    """What the learner says about an EvalResult."""

    def check() -> None:
        validate_eval_result(parse_message(raw, pb.EvalResult, max_bytes=limit))

    return reason_of(check)


def replay_eval_verdict(raw: bytes) -> str:
    """What the replay says: the learner's checks, and an epoch its log can hold."""
    verdict = eval_verdict(raw, limit=MAX_BYTES)
    if verdict == VALID and pb.EvalResult.FromString(raw).epoch > MAX_SEQUENCE:
        return "bad_value"
    return verdict


def header_verdict(raw: bytes) -> str:
    return reason_of(lambda: decode_header(raw, goal_dim=SPEC.goal_dim))


def batch_verdict(raw: bytes) -> str:
    return reason_of(lambda: decode_served_batch(raw, spec=SPEC, k=K, batch_size=LEARNER_B,
                                                 num_minibatches=LEARNER_N))


class ModelOracle:
    """What the replay does with a ClusterModel put: a reject reason, "adopted" or "ignored"
    (not newer than the model it has). It tracks the version the replay must hold."""

    def __init__(self) -> None:
        self.version = 0

    def __call__(self, raw: bytes) -> str:
        try:
            msg = parse_message(raw, pb.ClusterModel, max_bytes=MAX_BYTES)
            validate_centroids(msg, k=K, goal_dim=SPEC.goal_dim)
            if msg.version > MAX_SEQUENCE:  # the replay's log could not hold it
                return "bad_value"
            with np.errstate(over="ignore"):  # float64 beyond float32: inf, refused
                model = ClusterModel(version=int(msg.version),
                                     centroids=msg_to_array(msg.centroids),
                                     n_goals=int(msg.fitted_on),
                                     failures_seen=int(msg.failures_seen))
        except InvalidMessage as exc:
            return str(exc.reason)
        except ValueError:
            return "bad_value"
        if model.version <= self.version:
            return "ignored"
        self.version = model.version
        return "adopted"


WEIGHTS_DECODER = ActorBuilder(ACTOR_CONFIG).decoder()


def weights_verdict(raw: bytes) -> tuple[str, pb.Weights | None]:
    """(what the actor's decoder says, the parsed message if it parses)."""
    try:
        msg = WEIGHTS_DECODER.parse(raw)
    except InvalidMessage as exc:
        return str(exc.reason), None
    return reason_of(lambda: WEIGHTS_DECODER.decode(msg)), msg
