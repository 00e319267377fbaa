"""One test per reject reason: a bad episode is refused with a reason naming what and where."""

from collections.abc import Callable

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.rl.task_registry import task_spec
from hercs.wire.codec import array_to_msg, episode_to_msg
from hercs.wire.validation import (
    decode_episode,
    parse_message,
    validate_centroids,
    validate_episode,
    validate_sample_request,
)


def rejected(check: Callable[[], object]) -> InvalidMessage | None:
    """What a validator raised (None: it accepted the message)."""
    try:
        check()
    except InvalidMessage as exc:
        return exc
    return None

SPEC = task_spec("push")
MAX = 1 << 20


def good_message() -> pb.Episode:
    episode = random_episode(SPEC, np.random.default_rng(0), actor_id="actor-0", seq=1)
    return episode_to_msg(episode, run="run1", task="push")


def test_good_episode_decodes() -> None:
    msg, episode = decode_episode(good_message().SerializeToString(), SPEC, run="run1",
                                  max_bytes=MAX)
    assert msg == good_message()
    assert episode.obs.shape == (51, 25) and episode.actor_id == "actor-0"


def _set_array(field: str, value: np.ndarray) -> Callable[[pb.Episode], None]:
    def mutate(msg: pb.Episode) -> None:
        array_to_msg(value, out=getattr(msg, field))
    return mutate


def _nan_at(field: str, index: tuple[int, int]) -> Callable[[pb.Episode], None]:
    def mutate(msg: pb.Episode) -> None:
        shape = tuple(getattr(msg, field).shape)
        arr = np.zeros(shape, np.float32)
        arr[index] = np.nan
        array_to_msg(arr, out=getattr(msg, field))
    return mutate


def _truncate_data(msg: pb.Episode) -> None:
    msg.ag.data = msg.ag.data[:-4]


CASES: list[tuple[str, Callable[[pb.Episode], None], Reason, str]] = [
    ("schema", lambda m: setattr(m, "schema_version", 99), Reason.SCHEMA_VERSION,
     "schema_version 99"),
    ("run", lambda m: setattr(m, "run", "other"), Reason.UNKNOWN_RUN, "'other'"),
    ("task", lambda m: setattr(m, "task", "slide"), Reason.WRONG_TASK, "'slide'"),
    ("actor", lambda m: setattr(m, "actor_id", ""), Reason.MISSING_FIELD, "actor_id"),
    ("missing-array", lambda m: m.ClearField("actions"), Reason.MISSING_FIELD,
     "Episode.actions is missing"),
    ("dtype", _set_array("obs", np.zeros((51, 25), np.float64)), Reason.BAD_DTYPE,
     "Episode.obs: dtype 'float64'"),
    ("dims", _set_array("obs", np.zeros((51, 10), np.float32)), Reason.BAD_SHAPE,
     "Episode.obs: shape (51, 10), expected (51, 25)"),
    ("rank", _set_array("g", np.zeros(150, np.float32)), Reason.BAD_SHAPE, "Episode.g"),
    ("length", _set_array("actions", np.zeros((40, 4), np.float32)), Reason.BAD_LENGTH,
     "Episode.actions: 40 steps"),
    ("bytes", _truncate_data, Reason.BAD_ARRAY, "Episode.ag"),
    ("nan", _nan_at("obs", (7, 3)), Reason.NON_FINITE, "index (7, 3)"),
    ("inf", lambda m: _set_array("g", np.full((50, 3), np.inf, np.float32))(m),
     Reason.NON_FINITE, "Episode.g"),
]


@pytest.mark.parametrize(("mutate", "reason", "detail"), [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_reject_reason(mutate, reason: Reason, detail: str) -> None:
    msg = good_message()
    mutate(msg)
    rejection = rejected(lambda: validate_episode(msg, SPEC, run="run1"))
    assert rejection is not None
    assert rejection.reason == reason
    assert detail in rejection.detail
    with pytest.raises(InvalidMessage) as err:
        decode_episode(msg.SerializeToString(), SPEC, run="run1", max_bytes=MAX)
    assert err.value.reason == reason.value


def test_undecodable_bytes() -> None:
    with pytest.raises(InvalidMessage) as err:
        decode_episode(b"\xff\xff\xff\xff garbage", SPEC, run="run1", max_bytes=MAX)
    assert err.value.reason == Reason.UNDECODABLE
    assert "do not parse" in err.value.detail


def test_bytes_that_parse_but_are_not_ours_fail_the_schema_check() -> None:
    with pytest.raises(InvalidMessage) as err:
        decode_episode(b"", SPEC, run="run1", max_bytes=MAX)
    assert err.value.reason == Reason.SCHEMA_VERSION
    assert "not a hercs message" in err.value.detail


def test_oversized_is_rejected_before_parsing() -> None:
    raw = good_message().SerializeToString()
    with pytest.raises(InvalidMessage) as err:
        decode_episode(raw, SPEC, run="run1", max_bytes=len(raw) - 1)
    assert err.value.reason == Reason.OVERSIZED
    assert str(len(raw)) in err.value.detail


def test_any_run_accepted_when_not_checked() -> None:
    msg = good_message()
    msg.run = "other"
    assert rejected(lambda: validate_episode(msg, SPEC, run=None)) is None


def test_parse_message_checks_schema_of_any_type() -> None:
    raw = pb.SampleRequest(schema_version=2, num_minibatches=1, batch_size=1).SerializeToString()
    with pytest.raises(InvalidMessage, match="schema_version"):
        parse_message(raw, pb.SampleRequest, max_bytes=MAX)


@pytest.mark.parametrize(("minibatches", "batch_size", "ok"),
                         [(40, 256, True), (0, 256, False), (41, 256, False), (40, 0, False),
                          (1, 5000, False), (40, 4096, False), (25, 4096, True)],
                         ids=["ok", "zero-mb", "too-many-mb", "zero-batch", "huge-batch",
                              "reply-too-big", "reply-at-the-bound"])
def test_sample_request_bounds(minibatches: int, batch_size: int, ok: bool) -> None:
    msg = pb.SampleRequest(schema_version=1, run="run1", num_minibatches=minibatches,
                           batch_size=batch_size)
    rejection = rejected(lambda: validate_sample_request(
        msg, run="run1", max_minibatches=40, max_batch_size=4096, max_rows=25 * 4096))
    assert (rejection is None) == ok
    if not ok:
        assert rejection is not None and rejection.reason == Reason.BAD_VALUE


def test_centroid_checks() -> None:
    msg = pb.ClusterModel(schema_version=1, version=1,
                          centroids=array_to_msg(np.zeros((8, 3), np.float32)))
    assert rejected(lambda: validate_centroids(msg, k=8)) is None
    assert rejected(lambda: validate_centroids(msg, k=4)).reason == Reason.BAD_SHAPE
    bad = np.zeros((8, 3), np.float32)
    bad[2, 1] = np.nan
    array_to_msg(bad, out=msg.centroids)
    assert rejected(lambda: validate_centroids(msg, k=8)).reason == Reason.NON_FINITE
