"""The errors of the Zenoh layer (hercs.net.transport, hercs.net.queries); each message says which
endpoint or key."""

from __future__ import annotations

from hercs.errors import HercsError, Unreachable


class TransportError(HercsError):
    """A Zenoh session or exchange failed; the message says which endpoint or key."""


class ConnectAborted(TransportError):
    """`open_session` gave up waiting for the router because its stop event was set."""


class TransportTimeout(TransportError):
    """A request got no reply within `timeout_s`: no queryable appeared on the key, or the one
    that got it did not answer in time (it may have been held by backpressure).

    An insert that timed out may still have been applied: retry it unchanged (the replay
    deduplicates by `(actor_id, seq)`).
    """

    def __init__(self, key: str, timeout_s: float, why: str, *,
                 no_queryable: bool = False) -> None:
        super().__init__(f"request to {key!r}: {why} within {timeout_s:g} s; the caller "
                         "may retry")
        self.key = key
        self.timeout_s = timeout_s
        self.no_queryable = no_queryable
        """No queryable matched the key (rather than one that held the query too long)."""


class RouterUnreachable(TransportError, Unreachable):
    """No router answered at the `connect` endpoints within the client's `connect_timeout_s`."""


class RemoteError(TransportError):
    """The queryable answered with an error: `reason` (a `hercs.reasons.Reason` value,
    `internal` or `unavailable`) and `detail`. A rejected message is never retried unchanged."""

    def __init__(self, key: str, reason: str, detail: str) -> None:
        super().__init__(f"request to {key!r} rejected: {reason}: {detail}")
        self.key = key
        self.reason = reason
        self.detail = detail
