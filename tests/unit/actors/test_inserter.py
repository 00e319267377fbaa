"""hercs.actors.inserter: an episode refused for fair sharing (`actor_queue_full`) is kept and sent
again, the same bytes after the backoff, until it is acked; never dropped."""

from __future__ import annotations

import threading

from hercs.actors.inserter import Inserter
from hercs.net.transport import RemoteError
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason

WAIT_S = 15.0


def test_an_insert_refused_as_actor_queue_full_is_retried_with_the_same_bytes() -> None:
    sent: list[bytes] = []

    def send(payload: bytes) -> bytes:
        sent.append(payload)
        if len(sent) <= 2:  # the replay holds 4 of this actor's inserts already, twice
            raise RemoteError("replay/insert", Reason.ACTOR_QUEUE_FULL, "4 waiting")
        return pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id="a", seq=7,
                            episode_id=0).SerializeToString()

    inserter = Inserter(send=send, actor_id="a", backoff_min_s=0.01, backoff_max_s=0.02)
    running = threading.Event()
    assert inserter.submit(7, b"episode 7", stop=running)
    assert inserter.wait_idle(stop=running)
    c = inserter.counters
    assert (c.acked, c.retries, c.dropped, c.superseded, c.abandoned) == (1, 2, 0, 0, 0)
    assert sent == [b"episode 7"] * 3
    inserter.close(timeout_s=1.0)
    assert inserter.join(WAIT_S)


def test_abort_ends_a_retrying_delivery_at_once_and_takes_nothing_more() -> None:
    """A run that is over: its replay answers `unavailable` while it closes. `abort` (the
    actor's call on the learner's "finished") ends the delivery in its backoff without another
    attempt, abandons what is queued and refuses what comes next."""
    sent: list[bytes] = []
    refused = threading.Event()

    def send(payload: bytes) -> bytes:
        sent.append(payload)
        refused.set()
        raise RemoteError("replay/insert", Reason.UNAVAILABLE, "replay closing")

    # a backoff far longer than the test: only abort can end the wait
    inserter = Inserter(send=send, actor_id="a", backoff_min_s=60.0, backoff_max_s=60.0)
    running = threading.Event()
    assert inserter.submit(1, b"episode 1", stop=running)
    assert inserter.submit(2, b"episode 2", stop=running)
    assert refused.wait(WAIT_S)
    inserter.abort()
    assert inserter.join(WAIT_S), "the sender thread ends without waiting out its backoff"
    assert not inserter.submit(3, b"episode 3", stop=running)
    c = inserter.counters
    assert (c.acked, c.abandoned, c.retries) == (0, 2, 0) and sent == [b"episode 1"]
