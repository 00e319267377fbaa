"""A service told to stop while a cut has left it without its router exits 0 promptly: its
session's reopen (hercs.net.rediscovery.CutOff) was waiting for the router when SIGTERM came,
and the stop ends that wait at the end of the connect window under way, as it ends the first
connect's (test_stop_while_connecting.py). The cut is the router closed, on loopback."""

import queue
import signal
import sys
from pathlib import Path

import pytest

from hercs.net.transport import Transport
from hercs.proto.keys import RunKeys
from tests.integration.launcher_standins import Launcher
from tests.support import free_endpoint

pytestmark = pytest.mark.integration

JOINED_S = 60.0
"""How long the actor may take to start and connect."""
CUT_OFF_S = 10.0
"""`transport.cut_off_s` at the config's floor."""
REOPEN_S = 60.0
"""How long after the cut the reopen may take to be called: the bound, counted from the send
of a request that ended without a router, so at most the bound plus one request (join_run
asks for the run's config for 10 s at a time), with room for a slow machine."""
STOP_S = 10.0
"""The stop ends the reopen's wait once the connect attempt under way ends (at most 4 s,
hercs/net/sessions.py), then the actor stops."""


def test_sigterm_while_a_cut_off_session_waits_for_its_router(tmp_path: Path) -> None:
    endpoint = free_endpoint()
    alive = RunKeys("nobody").alive("actor", "x")
    router = Transport.open(mode="router", listen=[endpoint])
    monitor = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=JOINED_S)
    joined: queue.Queue[tuple[str, bool]] = queue.Queue()
    monitor.watch_alive(alive, lambda key, up: joined.put((key, up)))
    proc = Launcher([sys.executable, "-m", "hercs.apps.cli", "actor", "--run", "nobody",
                     "--connect", endpoint, "--id", "x",
                     "--set", f"transport.cut_off_s={CUT_OFF_S:g}"], cwd=tmp_path)
    try:
        # connected; it now asks for its run's config, which no replay serves
        assert joined.get(timeout=JOINED_S) == (alive, True)
        monitor.close()
        router.close()  # the cut
        proc.wait_for_line("reopening this process's Zenoh session: no router", REOPEN_S)
        assert proc.proc.poll() is None, f"it ended before it was told to stop: {proc.err}"
        proc.proc.send_signal(signal.SIGTERM)
        code = proc.finish(STOP_S)  # TimeoutExpired: the stop did not end the reopen's wait
    finally:
        proc.kill()
        monitor.close()
        router.close()
    said = "\n".join(proc.err)
    assert code == 0, said
    assert f"actor: got signal {signal.SIGTERM.value}, stopping" in said, said
    assert "Zenoh session reopened" not in said and "Traceback" not in said, said
