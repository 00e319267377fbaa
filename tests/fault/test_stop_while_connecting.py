"""A service told to stop while its router is still unreachable exits 0 promptly."""

import signal
import subprocess
import sys

import pytest

from tests.support import free_endpoint

pytestmark = pytest.mark.integration


@pytest.mark.parametrize("service", ["clusterer", "actor"])
def test_sigterm_while_waiting_for_router(service: str) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "hercs.apps.cli", service, "--run", "nobody",
         "--connect", free_endpoint(), "--id", "x"],
        stderr=subprocess.PIPE, text=True)
    try:
        for line in proc.stderr:  # the first failed attempt is logged at once
            if "waiting for a Zenoh router" in line:
                break
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
