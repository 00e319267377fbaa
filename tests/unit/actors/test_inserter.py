"""hercs.actors.inserter: an episode refused for fair sharing (`actor_queue_full`) is kept and sent
again, the same bytes after the backoff, until it is acked; never dropped."""

from __future__ import annotations

import threading

from hercs.actors.inserter import Inserter
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Reason
from hercs.transport import RemoteError

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
