"""The replay's counters for the learner's epoch rows, read over `replay/status_at`.

An epoch's row reports the counters as they stood when its last batch was drawn: the batch
names that moment (`ServedBatch.samples_served`) and the replay keeps the counters of its
newest batches, so two lockstep runs with one seed write the same rows whatever their timing.
"""

from __future__ import annotations

import logging

from hercs.errors import HercsError, InvalidMessage
from hercs.net.service_shell import ServiceRuntime
from hercs.net.transport import RemoteError, TransportError, TransportTimeout
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.served import ReplayCounters, decode_status, status_request

log = logging.getLogger("hercs.learner")

RETRY_S = 0.5


class Stopping(HercsError):
    """The service stopped while the learner waited for the replay's counters."""


class ReplayStatusClient:
    """Asks the run's replay for the counters of a served batch's moment, until it answers."""

    def __init__(self, runtime: ServiceRuntime, *, timeout_s: float, max_bytes: int) -> None:
        """`timeout_s`: one request's wait (`replay.sample_timeout_s`, as a batch's);
        `max_bytes`: the largest reply taken (`replay.max_message_bytes`)."""
        self.runtime = runtime
        self.timeout_s = timeout_s
        self.max_bytes = max_bytes
        self.warn = WarnOncePerMinute(log)

    def __call__(self, samples: int) -> ReplayCounters:
        """The counters once `samples` minibatches were served. The row cannot be written
        without them and the next batch needs the same replay, so a replay that is down or
        answers garbage is asked again (warned once a minute); raises `Stopping` if the service
        stops first."""
        runtime = self.runtime
        while not runtime.stop.is_set():
            try:
                raw = runtime.transport.request(runtime.keys.status_at, status_request(samples),
                                                timeout_s=self.timeout_s)
                counters = decode_status(raw, max_bytes=self.max_bytes)
            except InvalidMessage as exc:
                self.warn.warn(f"bad:{exc.reason}", f"skipped a bad ReplayStatus ({exc}); "
                                                    "asking again")
            except (TransportTimeout, RemoteError, TransportError) as exc:
                self.warn.warn(type(exc).__name__, f"replay status request failed ({exc}); "
                                                   "retrying")
            else:
                if counters.samples != samples:  # a restarted replay: that moment is gone
                    log.info("the replay no longer holds the counters of %d samples served "
                             "(it has served %d); the row reports the current ones", samples,
                             counters.samples)
                return counters
            runtime.stop.wait(RETRY_S)
        raise Stopping("stopped while waiting for the replay's status")
