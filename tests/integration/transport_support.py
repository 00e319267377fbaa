"""What the tests of hercs.net.transport share: the run prefix, the wait, an echo handler
(the open_client fixture's type, OpenClient, is in services.py)."""

from __future__ import annotations

RUN = "hercs/test"
WAIT_S = 5.0


def echo(payload: bytes) -> bytes:
    return b"echo:" + payload
