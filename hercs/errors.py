"""The project's error hierarchy. Messages name the offending value and what happens next."""

from __future__ import annotations

from hercs.reasons import Reason


class HercsError(Exception):
    """Base of every error hercs raises on purpose."""


class ConfigError(HercsError, ValueError):
    """A configuration value is invalid; the process refuses to start with it."""


class Diverged(HercsError):
    """The learner's losses or weights are no longer finite numbers: nothing trains from them
    again, and a restart from the checkpoint with the same config would most likely diverge
    the same way. The learner publishes and saves nothing of them and exits with its own
    status (`hercs.net.service_shell.EXIT_DIVERGED`), which ends the whole run."""


class InvalidMessage(HercsError):
    """A wire message was rejected; it never reaches a buffer, the clusterer or the learner.

    `reason` is one of `hercs.reasons.Reason`'s values, counted by reason in
    `ReplayStatus`; `detail` says what was wrong and where.
    """

    def __init__(self, reason: Reason, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


class SamplingError(HercsError):
    """A batch could not be drawn (e.g. the replay is empty); the request is answered with this."""


class Unreachable(HercsError):
    """A client gave up waiting (`transport.wait_s`) for its router or its run; the message
    says what it waited for and, when the router answered, which runs it knows."""
