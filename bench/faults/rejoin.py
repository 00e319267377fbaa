"""Does a client come back after a partition? Repeated cuts of one client's link, each followed
by the time until its next answered request.

    python -m bench.faults.rejoin --cuts 2 12 30 5 20  # as root; one line per cut and a summary

A router with mutual TLS on a veth link (bench.faults.netns); results: docs/FAULTS.md."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from bench.common import script_parser
from bench.faults.netns import Host, hosts, problem
from hercs.apps.deploy.certs import make_certs
from hercs.apps.launch.child_process import stop_process
from hercs.apps.launch.router import free_port, open_router
from hercs.config import SecurityConfig
from hercs.net.security import zenoh_settings
from hercs.net.transport import Transport, TransportError
from hercs.proto.keys import RunKeys

RUN = "rejoin"
SUBNET = "10.122"
"""Its own links (test_remote_actor_netns uses 10.123, minislurm 10.124, bench.faults.net_faults
10.125, bench.faults.chaos 10.126)."""
REQUEST_TIMEOUT_S = 2.0
"""The client's per-request timeout: short, so that an answer after the heal is not hidden
behind a request sent into the cut."""
REJOIN_BOUND_S = 45.0
"""What a cut's `rejoined_s` must stay under: the longest a broken-but-reconnected session
goes unnoticed (`TransportConfig.rediscover_s`, 20 s), plus a reopen across TLS (a few
seconds), plus Zenoh's own reconnection after a cut longer than its lease (its retry period
grows to a few seconds), with room for a loaded machine."""


def _security(certs: Path) -> SecurityConfig:
    return SecurityConfig(tls_ca=str(certs / "ca.pem"), tls_cert=str(certs / "{role}.pem"),
                          tls_key=str(certs / "{role}.key"))


def client_main(endpoint: str, certs: Path) -> int:
    """The namespaced client: request, print each answer, until SIGTERM."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    settings = zenoh_settings(_security(certs), mode="client", role="actor",
                              endpoints=[endpoint])
    key = RunKeys(RUN).insert
    with Transport.open(mode="client", connect=[endpoint], settings=settings,
                        stop=stop) as transport:
        seq = 0
        while not stop.is_set():
            sent = time.time()
            try:
                reply = transport.request(key, str(seq).encode(), timeout_s=REQUEST_TIMEOUT_S)
            except TransportError as exc:
                print(json.dumps({"seq": seq, "failed": str(exc)[:120], "at": time.time()}),
                      flush=True)
                stop.wait(0.2)
                continue
            assert reply == str(seq).encode(), (reply, seq)
            print(json.dumps({"seq": seq, "sent": sent, "at": time.time()}), flush=True)
            seq += 1
            stop.wait(0.1)
    return 0


@dataclass
class Cut:
    length_s: float
    cut_at: float
    healed_at: float
    rejoined_s: float | None
    """From the heal to the first answer to a request sent after it (None: none came)."""


class _Answers:
    """The client's answers, read from its stdout on a thread."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: list[dict[str, float | str]] = []
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            with self._cond:
                self.lines.append(row)
                self._cond.notify_all()

    def wait_answer_sent_after(self, t: float, timeout_s: float) -> float | None:
        """The wall time of the first answer to a request sent after `t`, or None."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for row in self.lines:
                    if "sent" in row and float(row["sent"]) >= t:
                        return float(row["at"])
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)


def probe(cuts: Sequence[float], *, host: Host, certs: Path,
          bound_s: float = REJOIN_BOUND_S) -> list[Cut]:
    """Cut `host`'s link for each length in `cuts` (after the client has been answered),
    heal it, and wait up to `bound_s` for the next answer."""
    port = free_port("0.0.0.0")  # every address: the router listens on each link
    endpoint = f"tls/{host.host_ip}:{port}"
    local = f"tls/127.0.0.1:{port}"
    security = _security(certs)
    router = open_router([endpoint, local], security)
    replay = Transport.open(mode="client", connect=[local], connect_timeout_s=30,
                            settings=zenoh_settings(security, mode="client", role="replay",
                                                    endpoints=[local]))
    proc: subprocess.Popen[str] | None = None
    out: list[Cut] = []
    try:
        replay.serve(RunKeys(RUN).insert, lambda payload: payload)
        env = dict(os.environ, HERCS_LOG=os.environ.get("HERCS_LOG", "INFO"))
        proc = subprocess.Popen(
            host.exec_argv([sys.executable, "-m", "bench.faults.rejoin", "--client", endpoint,
                            "--certs", str(certs)]),
            stdout=subprocess.PIPE, text=True, env=env)
        answers = _Answers(proc)
        if answers.wait_answer_sent_after(time.time(), 60.0) is None:
            raise RuntimeError("the namespaced client was never answered before any cut")
        for length in cuts:
            cut_at = time.time()
            host.cut()
            time.sleep(length)  # the fault's length is the experiment: nothing to await
            host.heal()
            healed_at = time.time()
            at = answers.wait_answer_sent_after(healed_at, bound_s)
            cut = Cut(length, cut_at, healed_at, None if at is None else at - healed_at)
            out.append(cut)
            print(f"cut {length:5.1f} s: next answer {_s(cut.rejoined_s)} after the heal",
                  flush=True)
            if at is None:
                break
    finally:
        if proc is not None:
            stop_process(proc, signal.SIGTERM, grace_s=15)
        replay.close()
        router.close()
    return out


def _s(value: float | None) -> str:
    return "never" if value is None else f"{value:.1f} s"


def main(argv: list[str] | None = None) -> int:
    parser = script_parser("bench.faults.rejoin", __doc__)
    parser.add_argument("--cuts", type=float, nargs="+", default=[2.0, 12.0, 30.0, 5.0, 20.0],
                        help="cut lengths in seconds, in order")
    parser.add_argument("--client", metavar="ENDPOINT", help=argparse.SUPPRESS)
    parser.add_argument("--certs", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.client:
        from hercs.net.service_shell import setup_logging
        setup_logging("actor")
        return client_main(args.client, args.certs)
    if (why := problem(SUBNET)) is not None:
        print(f"cannot run: {why}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp, hosts(1, subnet=SUBNET) as (host,):
        make_certs(Path(tmp), hosts=[host.host_ip])
        cuts = probe(args.cuts, host=host, certs=Path(tmp))
    missed = [c.length_s for c in cuts if c.rejoined_s is None]
    print(f"{len(cuts)} cuts; never rejoined after: {missed or 'none'}")
    return 1 if missed or len(cuts) < len(args.cuts) else 0


if __name__ == "__main__":
    sys.exit(main())
