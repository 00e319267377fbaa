"""How `hercs.net.queries.request` names a timeout, driven with stand-ins for its two Zenoh
calls (the real sessions are tests/integration/test_transport.py's): a queryable that let gets
end unanswered and then let the last one run into the deadline is still one that did not answer
(`no_queryable`, what rediscovery counts), on a machine slow enough that its empty answer came
late; one that appeared and then held the request is a request with no reply."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from hercs.net import queries
from hercs.net.transport_errors import TransportTimeout


class Session:
    def is_closed(self) -> bool:
        return False


def script(monkeypatch: pytest.MonkeyPatch, found: str) -> None:
    """One get ends unanswered, the queryable is `found`, the next get runs out of time."""
    gets: Iterator[bool] = iter([False, True])

    def get_one(session, key, payload, *, deadline, timeout_s):  # type: ignore[no-untyped-def]
        if next(gets):
            raise TransportTimeout(key, timeout_s, "no reply")
        return None

    monkeypatch.setattr(queries, "_get_one", get_one)
    monkeypatch.setattr(queries, "_wait_for_queryable", lambda session, key, t: found)


def test_a_silent_queryable_whose_last_get_timed_out_did_not_answer(
        monkeypatch: pytest.MonkeyPatch) -> None:
    script(monkeypatch, "known")
    with pytest.raises(TransportTimeout, match="no queryable answered within 1 s") as caught:
        queries.request(Session(), "k", b"", timeout_s=1.0)  # type: ignore[arg-type]
    assert caught.value.no_queryable


def test_a_new_queryable_that_holds_the_request_gave_no_reply(
        monkeypatch: pytest.MonkeyPatch) -> None:
    script(monkeypatch, "appeared")
    with pytest.raises(TransportTimeout, match="no reply within 1 s") as caught:
        queries.request(Session(), "k", b"", timeout_s=1.0)  # type: ignore[arg-type]
    assert not caught.value.no_queryable
