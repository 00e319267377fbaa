"""hercs.net.backoff: the delays double from the first up to the ceiling, and a stop ends a wait."""

from __future__ import annotations

import threading

import pytest

from hercs.net.backoff import Backoff, nth_delay


def test_delays_double_up_to_the_ceiling_and_reset() -> None:
    backoff = Backoff(0.1, 2.0)
    stop = threading.Event()
    stop.set()  # every wait returns at once, as a stop would make it
    seen = []
    for _ in range(7):
        seen.append(backoff.next_s)
        assert backoff.wait(stop)
    assert seen == pytest.approx([0.1, 0.2, 0.4, 0.8, 1.6, 2.0, 2.0])
    backoff.reset()
    assert backoff.next_s == 0.1
    assert nth_delay(1.0, 3, 30.0) == 8.0 and nth_delay(1.0, 10_000, 30.0) == 30.0


def test_a_backoff_without_a_positive_first_delay_is_refused() -> None:
    with pytest.raises(ValueError, match="got first 0, max 1"):
        Backoff(0, 1)
    with pytest.raises(ValueError, match="got first 2, max 1"):
        Backoff(2, 1)
