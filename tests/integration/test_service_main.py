"""`service_main`, the entry every service process runs: its exit statuses and its return
once the body is done, with a real router on loopback."""

from __future__ import annotations

import threading

import pytest

from hercs.config import HercsConfig
from hercs.errors import ConfigError
from hercs.net.service_shell import EXIT_CONFIG, EXIT_FAILED, ServiceRuntime, service_main
from hercs.net.signals import StopSignals
from hercs.net.transport import Transport

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]


def _config(endpoint: str) -> HercsConfig:
    return HercsConfig.from_dict({"run": {"name": "entry"},
                                  "transport": {"connect": [endpoint]}})


def test_returns_once_the_body_is_done_even_if_its_thread_lingers(
        router: Transport, endpoint: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The worker thread is still alive for a moment after it wakes the main thread. A main
    thread that waited again while the worker was alive never returned (a learner that had
    finished its epochs hung ~1 run in 4 under load). Widen that moment on purpose: the
    worker lingers after its wake-up, and `service_main` must still return."""
    lingering = threading.Event()
    wake = StopSignals.wake

    def wake_then_linger(self: StopSignals) -> None:
        wake(self)
        lingering.wait(0.2)  # nothing sets it: the worker just stays alive a while

    monkeypatch.setattr(StopSignals, "wake", wake_then_linger)
    for status in (0, 3):
        assert service_main(role="test", config=_config(endpoint),
                            body=lambda runtime, s=status: s) == status


@pytest.mark.parametrize(("error", "status"), [(ConfigError("bad value"), EXIT_CONFIG),
                                               (RuntimeError("boom"), EXIT_FAILED)])
def test_exit_status_of_a_failing_body(router: Transport, endpoint: str,
                                       error: Exception, status: int) -> None:
    def body(runtime: ServiceRuntime) -> int:
        raise error

    assert service_main(role="test", config=_config(endpoint), body=body) == status


def test_a_dead_supervised_thread_makes_the_exit_status_non_zero(
        router: Transport, endpoint: str) -> None:
    def body(runtime: ServiceRuntime) -> int:
        def crash() -> None:
            raise ValueError("a part died")

        runtime.start_thread(crash, name="part").join()
        assert runtime.stop.is_set()  # the crash stops the service
        return 0

    assert service_main(role="test", config=_config(endpoint), body=body) == EXIT_FAILED
