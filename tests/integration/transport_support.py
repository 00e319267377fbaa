"""What the tests of hercs.net.transport share: the run prefix, the wait, an echo handler, a
request sent from another thread (the open_client fixture's type, OpenClient, is in
services.py)."""

from __future__ import annotations

import queue
import threading

from hercs.net.transport import Transport

RUN = "hercs/test"
WAIT_S = 5.0


def request_in_background(
    client: Transport, key: str, payload: bytes
) -> queue.Queue[bytes | Exception]:
    """Sends the request from a thread of its own, so that the test can hold, answer or close
    the server meanwhile; the queue gets the reply, or the exception the request raised."""
    result: queue.Queue[bytes | Exception] = queue.Queue()

    def ask() -> None:
        try:
            result.put(client.request(key, payload, timeout_s=WAIT_S))
        except Exception as exc:
            result.put(exc)

    threading.Thread(target=ask).start()
    return result


def echo(payload: bytes) -> bytes:
    return b"echo:" + payload
