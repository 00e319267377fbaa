"""A service told to stop while its router is still unreachable exits 0 promptly."""

import subprocess
import sys

import pytest

from tests.support import free_endpoint, sigterm_after_line

pytestmark = pytest.mark.integration


@pytest.mark.parametrize("service", ["clusterer", "actor"])
def test_sigterm_while_waiting_for_router(service: str) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "hercs.apps.cli", service, "--run", "nobody",
         "--connect", free_endpoint(), "--id", "x"],
        stderr=subprocess.PIPE, text=True)
    # the first failed attempt is logged at once
    sigterm_after_line(proc, "waiting for a Zenoh router", timeout_s=10)
