"""A client that cannot reach its router or its run says what it waits for and, with
`transport.wait_s`, gives up with exit status 3 naming the runs the router knows."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator

import pytest

from hercs.net.service_shell import EXIT_UNREACHABLE
from hercs.net.transport import Transport
from hercs.proto.keys import RunKeys
from tests.support import free_endpoint, sigterm_after_line

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def _actor(endpoint: str, run: str, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "hercs.apps.cli", "actor", "--run", run, "--connect", endpoint,
         "--id", "lost", *extra], stderr=subprocess.PIPE, text=True)


@pytest.fixture
def router_with_a_run() -> Iterator[str]:
    """A router on loopback where run 'elsewhere' has a (stand-in) replay alive."""
    endpoint = free_endpoint()
    router = Transport.open(mode="router", listen=[endpoint])
    replay = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=10)
    replay.declare_alive(RunKeys("elsewhere").alive("replay", "replay-0"))
    yield endpoint
    replay.close()
    router.close()


def test_no_router_gives_up_after_wait_s() -> None:
    started = time.monotonic()
    proc = _actor(free_endpoint(), "nobody", "--set", "transport.wait_s=2")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_UNREACHABLE, err
    assert "no Zenoh router reachable" in err and "Traceback" not in err
    assert time.monotonic() - started < 30


def test_unknown_run_gives_up_naming_the_known_runs(router_with_a_run: str) -> None:
    proc = _actor(router_with_a_run, "nobody", "--set", "transport.wait_s=3")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_UNREACHABLE, err
    assert "run 'nobody': no replay served its config within transport.wait_s = 3 s" in err
    assert "runs with a replay on this router: elsewhere" in err
    assert "Traceback" not in err


def test_by_default_it_waits_and_says_for_what(router_with_a_run: str) -> None:
    proc = _actor(router_with_a_run, "nobody")
    # the first failed attempt is logged at once
    line = sigterm_after_line(proc, "waiting for run 'nobody'", timeout_s=20)
    assert "runs with a replay on this router: elsewhere" in line


@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_a_bad_wait_is_refused(value: str) -> None:
    proc = _actor(free_endpoint(), "nobody", "--set", f"transport.wait_s={value}")
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2, err
    assert "transport.wait_s" in err
