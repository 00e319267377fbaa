"""`hercs view --web`: the Rerun web viewer and the gRPC proxy its page reads the recording
from, served by the `rerun` binary and bound to one address: this machine's loopback unless
the user opens them to others with `--web-bind` (docs/SECURITY.md, "The web viewer").

rerun-sdk's own `serve_grpc` and `serve_web_viewer` bind every interface and take no address,
so anyone who reaches the host would see the run; the binary's `--bind` does take one.
"""

from __future__ import annotations

import contextlib
import importlib.util
import ipaddress
import signal
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from hercs.apps.launch.child_process import describe_exit, pdeathsig_preexec, stop_process
from hercs.errors import HercsError

DEFAULT_BIND = "127.0.0.1"
"""This machine only: a browser elsewhere needs `--web-bind` (or an SSH tunnel)."""
DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876
START_TIMEOUT_S = 60.0
"""How long the `rerun` process may take to listen on both ports (a cold start on a loaded
machine takes a few seconds)."""
_POLL_S = 0.1


class WebViewerError(HercsError):
    """The web viewer cannot be served as asked; the message says why and what to change."""


def bind_address(address: str) -> str:
    """`address` as the IP address `--web-bind` needs, or `WebViewerError` naming it."""
    try:
        return str(ipaddress.ip_address(address))
    except ValueError:
        raise WebViewerError(
            f"--web-bind: got {address!r}, must be an IP address of this machine: "
            f"{DEFAULT_BIND} (the default) for this machine only, one of its network "
            "addresses (`ip addr`), or 0.0.0.0 / :: for every interface") from None


def rerun_binary() -> str:
    """The `rerun` program itself. The `rerun` beside the interpreter is a Python wrapper that
    runs it as a child of its own, so a signal to the wrapper (our stop, the parent-death
    signal) would leave the server serving."""
    package = importlib.util.find_spec("rerun_cli")  # rerun-sdk's; it ships the program
    binary = Path(package.origin).parent / "rerun" if package and package.origin else None
    return str(binary) if binary is not None and binary.is_file() else "rerun"  # on PATH


def _url_host(address: str) -> str:
    return f"[{address}]" if ":" in address else address


@dataclass
class WebViewer:
    """A running `rerun --serve-web` process and the addresses it serves on."""

    proc: subprocess.Popen[bytes]
    bind: str
    web_port: int
    grpc_port: int

    @property
    def local_host(self) -> str:
        """Where this machine reaches the servers: loopback for a wildcard bind."""
        if ipaddress.ip_address(self.bind).is_unspecified:
            return "::1" if ":" in self.bind else "127.0.0.1"
        return self.bind

    @property
    def stream_url(self) -> str:
        """Where `hercs view` sends the recording."""
        return f"rerun+http://{_url_host(self.local_host)}:{self.grpc_port}/proxy"

    @property
    def page_url(self) -> str:
        """The page a browser opens: on this machine for a loopback bind, else by this
        host's name (a wildcard bind) or the address bound."""
        address = ipaddress.ip_address(self.bind)
        host = (self.local_host if address.is_loopback else
                socket.gethostname() if address.is_unspecified else self.bind)
        stream = f"rerun+http://{_url_host(host)}:{self.grpc_port}/proxy"
        return f"http://{_url_host(host)}:{self.web_port}/?url={stream}"

    def stop(self) -> None:
        stop_process(self.proc, signal.SIGTERM, grace_s=10.0)


def start_web_viewer(*, bind: str = DEFAULT_BIND, web_port: int | None = None,
                     grpc_port: int | None = None) -> WebViewer:
    """Start `rerun --serve-web` bound to `bind`, as a child that gets SIGTERM when this
    process dies, and wait until both ports accept
    connections; `WebViewerError` with rerun's own words if it ends first (a port in use, an
    address not of this machine) or is still not listening after `START_TIMEOUT_S`."""
    bind = bind_address(bind)
    web_port = DEFAULT_WEB_PORT if web_port is None else web_port
    grpc_port = DEFAULT_GRPC_PORT if grpc_port is None else grpc_port
    argv = [rerun_binary(), "--serve-web", "--bind", bind, "--port", str(grpc_port),
            "--web-viewer-port", str(web_port)]
    with tempfile.TemporaryFile() as said:
        # its own session: a Ctrl-C at the terminal reaches `hercs view` alone, which closes
        # its stream to the server before it stops the server
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=said,
                                stderr=subprocess.STDOUT, start_new_session=True,
                                preexec_fn=pdeathsig_preexec(signal.SIGTERM))
        viewer = WebViewer(proc=proc, bind=bind, web_port=web_port, grpc_port=grpc_port)
        try:
            _wait_listening(viewer)
        except WebViewerError as exc:
            viewer.stop()
            said.seek(0)
            words = " | ".join(said.read().decode(errors="replace").strip().splitlines()[-3:])
            raise WebViewerError(f"{exc}; rerun said: {words or 'nothing'}") from None
    return viewer


def _wait_listening(viewer: WebViewer) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    waiting = [viewer.grpc_port, viewer.web_port]
    while waiting:
        if viewer.proc.poll() is not None:
            raise WebViewerError(
                f"the web viewer did not start on {viewer.bind} (ports {viewer.grpc_port} and "
                f"{viewer.web_port}; give free ones with --grpc-port and --web-port): `rerun` "
                f"ended with {describe_exit(viewer.proc.returncode)}")
        if time.monotonic() > deadline:
            raise WebViewerError(f"the web viewer was not listening on {viewer.bind} ports "
                                 f"{waiting} after {START_TIMEOUT_S:g} s")
        with contextlib.suppress(OSError), socket.create_connection(
                (viewer.local_host, waiting[0]), timeout=1.0):
            waiting.pop(0)
            continue
        time.sleep(_POLL_S)  # rerun announces nothing we read: the port is the event
