"""`ParkedCalls`: one parked insert per (actor_id, seq) until it is stored or answered; expiry
takes waiting calls only, keeps the others' order and frees their keys."""

from __future__ import annotations

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.parked_calls import ParkedCalls, check_unstored, insert_key
from hercs.replay_service.table_calls import (
    EpisodeIdConflict,
    ParkedInsert,
    ParkedSample,
    SampleCall,
)
from hercs.rl.task_registry import task_spec

RNG = np.random.default_rng(0)


def parked_insert(actor: str, seq: int, deadline: float | None) -> ParkedInsert:
    episode = random_episode(task_spec("reach"), RNG, actor_id=actor, seq=seq)
    return ParkedInsert([], deadline, episode=episode, record=pb.Episode())


def parked_sample(deadline: float | None) -> ParkedSample:
    return ParkedSample([], deadline, call=SampleCall(num_minibatches=1, batch_size=4))


def test_a_parked_insert_is_joined_by_its_key_until_it_is_forgotten() -> None:
    calls = ParkedCalls(waiting_inserts_per_actor=4)
    item = parked_insert("a", 7, None)
    calls.park_insert(item)
    assert calls.joined(("a", 7)) is item and calls.joined(("a", 8)) is None
    calls.ready.append(calls.inserts.popleft())  # admitted: still joined by a retry
    assert calls.joined(("a", 7)) is item and calls.waiting() == (0, 0)
    assert calls.take_ready() == [item] and calls.ready == []
    calls.forget(item)
    assert calls.joined(insert_key(item.episode)) is None


def test_expiry_takes_the_waiting_calls_past_their_deadline_and_frees_their_keys() -> None:
    calls = ParkedCalls(waiting_inserts_per_actor=4)
    early, late, never = (parked_insert("a", 1, 5.0), parked_insert("a", 2, 9.0),
                          parked_insert("b", 1, None))
    admitted = parked_insert("c", 1, 1.0)
    calls.park_insert(admitted)
    calls.ready.append(calls.inserts.popleft())  # as the drain does: logged, never expired
    for item in (early, late, never):
        calls.park_insert(item)
    s1, s2 = parked_sample(4.0), parked_sample(None)
    calls.park_sample(s1)
    calls.park_sample(s2)
    assert calls.waiting() == (3, 2)
    gone = calls.take_expired(6.0)
    assert gone == [early, s1]
    assert calls.waiting() == (2, 1) and list(calls.samples) == [s2]
    assert calls.joined(("a", 1)) is None and calls.joined(("a", 2)) is late
    assert calls.joined(("c", 1)) is admitted and calls.ready == [admitted]


def test_a_group_holding_a_stored_or_repeated_episode_is_refused_before_it_is_logged() -> None:
    one, two = parked_insert("a", 1, None), parked_insert("a", 2, None)
    check_unstored({}, [one, two])
    with pytest.raises(EpisodeIdConflict, match=r"\(actor 'a', seq 2\) stored as episode 5"):
        check_unstored({("a", 2): 5}, [one, two])
    with pytest.raises(EpisodeIdConflict, match=r"\(actor 'a', seq 1\) twice in it"):
        check_unstored({}, [one, parked_insert("a", 1, None)])
