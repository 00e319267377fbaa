"""A service told to stop while its router is still unreachable exits 0 promptly: it was
waiting for the router when SIGTERM came (it had said so and was still running), the signal
ended that wait (it says it stopped while waiting, after it got the signal, and it never
connected), and it exited within a connect window of the signal."""

import signal
import sys
from pathlib import Path

import pytest

from tests.integration.launcher_standins import Launcher
from tests.support import free_endpoint

pytestmark = pytest.mark.integration

WAITING_S = 60.0
"""How long the service may take to start and say it waits (its first attempt lasts 1 s)."""
STOP_S = 10.0
"""The stop ends the wait once the connect attempt under way ends (at most 4 s,
hercs/net/sessions.py), then the service stops."""


@pytest.mark.parametrize("service", ["clusterer", "actor"])
def test_sigterm_while_waiting_for_router(service: str, tmp_path: Path) -> None:
    proc = Launcher([sys.executable, "-m", "hercs.apps.cli", service, "--run", "nobody",
                     "--connect", free_endpoint(), "--id", "x"], cwd=tmp_path)
    try:
        proc.wait_for_line("waiting for a Zenoh router", WAITING_S)
        assert proc.proc.poll() is None, f"it ended before it was told to stop: {proc.err}"
        proc.proc.send_signal(signal.SIGTERM)
        code = proc.finish(STOP_S)  # TimeoutExpired: the stop did not end the wait
    finally:
        if proc.proc.poll() is None:
            proc.proc.kill()
            proc.proc.wait()
    said = "\n".join(proc.err)
    assert code == 0, said
    got = said.find(f"{service}: got signal {signal.SIGTERM.value}, stopping")
    stopped = said.find("stopped while waiting for a Zenoh router")
    assert 0 <= got < stopped, f"the signal did not end the wait:\n{said}"
    assert "connected to Zenoh" not in said and "Traceback" not in said, said
