"""`hercs view RUN --web` serves the run to this machine only unless told otherwise (issue 46):
the real command is started on a real run log, and the sockets its process tree listens on
are read from the kernel (psutil); the web viewer's page is fetched over HTTP; opening it to
others takes `--web-bind`; the server never outlives the command."""

from __future__ import annotations

import contextlib
import ipaddress
import signal
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import psutil
import pytest

from hercs.apps.cli.main import main
from hercs.apps.launch.router import free_port
from tests.integration.launcher_standins import Launcher
from tests.unit.apps.test_view import _write_run

pytestmark = pytest.mark.integration

SERVE_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 30.0


def listening(pid: int) -> set[tuple[str, int]]:
    """(address, port) of every TCP socket `pid` and its descendants listen on."""
    parent = psutil.Process(pid)
    found = set()
    for proc in [parent, *parent.children(recursive=True)]:
        for conn in proc.net_connections(kind="tcp"):
            if conn.status == psutil.CONN_LISTEN:
                found.add((conn.laddr.ip, conn.laddr.port))
    return found


def serve(tmp_path: Path, *extra: str) -> tuple[Launcher, str, int, int]:
    """`hercs view --web` of a real log, once it says where it serves: (the command, the URL
    it printed, its web port, its gRPC port)."""
    run = tmp_path / "run"
    run.mkdir()
    _write_run(run)
    web, grpc = free_port(), free_port()
    view = Launcher([sys.executable, "-m", "hercs.apps.cli", "view", str(run), "--web",
                     "--no-browser", "--web-port", str(web), "--grpc-port", str(grpc),
                     *extra], cwd=tmp_path)
    line = view.wait_for_line(r"serving the web viewer at \S+", SERVE_TIMEOUT_S)
    return view, line.split("serving the web viewer at ")[1].split()[0], web, grpc


def stop(view: Launcher, sig: int = signal.SIGINT) -> list[psutil.Process]:
    """Stop the command with `sig`; the processes it had started, for the caller to check
    they are gone."""
    children = psutil.Process(view.proc.pid).children(recursive=True)
    view.proc.send_signal(sig)
    try:
        view.proc.wait(STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        view.proc.kill()  # a failed stop must not leave it serving
        for child in children:
            with contextlib.suppress(psutil.NoSuchProcess):
                child.kill()
        raise
    return children


def assert_gone(children: list[psutil.Process], after: str) -> None:
    _, alive = psutil.wait_procs(children, timeout=STOP_TIMEOUT_S)
    for proc in alive:
        proc.kill()
    assert not alive, f"the web viewer outlived {after}: {alive}"


def test_by_default_both_ports_listen_on_loopback_only(tmp_path: Path) -> None:
    view, url, web, grpc = serve(tmp_path)
    try:
        sockets = listening(view.proc.pid)
        assert {port for _, port in sockets} == {web, grpc}, sockets
        assert all(ipaddress.ip_address(address).is_loopback for address, _ in sockets), sockets
        assert url == f"http://127.0.0.1:{web}/?url=rerun+http://127.0.0.1:{grpc}/proxy"
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
    finally:
        children = stop(view)
    assert view.proc.returncode == 0, view.err
    assert_gone(children, "`hercs view` stopped with Ctrl-C")


def test_web_bind_opens_both_ports_to_every_interface_when_asked(tmp_path: Path) -> None:
    view, url, web, grpc = serve(tmp_path, "--web-bind", "0.0.0.0")
    try:
        assert listening(view.proc.pid) == {("0.0.0.0", web), ("0.0.0.0", grpc)}
        host = socket.gethostname()
        assert url == f"http://{host}:{web}/?url=rerun+http://{host}:{grpc}/proxy"
    finally:
        children = stop(view)
    assert_gone(children, "`hercs view` stopped with Ctrl-C")


def test_the_web_viewer_dies_with_a_killed_hercs_view(tmp_path: Path) -> None:
    """No exit code runs after SIGKILL: the parent-death signal stops the server."""
    view, _, _, _ = serve(tmp_path)
    children = stop(view, signal.SIGKILL)
    assert children, "hercs view --web started no server process"
    assert_gone(children, "a killed `hercs view`")


@pytest.mark.parametrize(("argv", "message"), [
    (["--web", "--web-bind", "everyone"],
     "--web-bind: got 'everyone', must be an IP address of this machine: 127.0.0.1 (the "
     "default) for this machine only"),
    (["--web-bind", "0.0.0.0", "--save", "x.rrd"],
     "--web-bind 0.0.0.0: goes with --web"),
], ids=["not-an-address", "without-web"])
def test_a_bad_web_bind_is_refused_before_the_log_is_read(
        tmp_path: Path, argv: list[str], message: str, capsys) -> None:
    assert main(["view", str(tmp_path / "no-such-run"), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"hercs view: {message}"), err  # not the missing run: checked first


def test_ctrl_c_at_the_terminal_stops_it_quietly(tmp_path: Path) -> None:
    """A Ctrl-C reaches the terminal's whole foreground process group: `hercs view` closes
    its stream before it stops the server, which has a session of its own, so nothing but its
    own lines is said (the severed connection gave two red Rerun ERROR lines)."""
    import os
    import time

    run = tmp_path / "run"
    run.mkdir()
    _write_run(run)
    view = subprocess.Popen(
        [sys.executable, "-m", "hercs.apps.cli", "view", str(run), "--web", "--no-browser",
         "--web-port", str(free_port()), "--grpc-port", str(free_port())],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)  # its own process group, as a terminal's foreground job
    try:
        deadline = time.monotonic() + SERVE_TIMEOUT_S
        assert view.stdout is not None
        while "serving the web viewer" not in view.stdout.readline():
            assert view.poll() is None and time.monotonic() < deadline, view.stderr
        children = psutil.Process(view.pid).children(recursive=True)
        assert children, "no server process"
        os.killpg(view.pid, signal.SIGINT)  # what the terminal does on Ctrl-C
        _, err = view.communicate(timeout=STOP_TIMEOUT_S)
    finally:
        if view.poll() is None:
            os.killpg(view.pid, signal.SIGKILL)
            view.wait()
    assert view.returncode == 0, err
    assert "ERROR" not in err and "\x1b[31m" not in err, err
    assert err.strip().startswith("hercs view:"), err
    assert_gone(children, "`hercs view` stopped with Ctrl-C")
