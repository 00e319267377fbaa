"""Does a request parked at a replay that is killed end when the replay comes back?

    python -m bench.faults.stranded_gets --kills 300 --timeout 30 --ask-again 5  # as learners

Each kill ends `answered`, `stranded` or `no_queryable`; prints one JSON line per kill and a
summary. The method and the counts measured: docs/results/faults.md."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass

from hercs.apps.launch.router import free_port
from hercs.net.transport import Transport, TransportTimeout

KEY = "strand/sample"

REPLAY = r'''
import sys, time
from hercs.net.transport import Transport
endpoint, mode = sys.argv[1:3]
transport = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=30)
held = []

def handle(pending):
    if mode == "park":
        held.append(pending)  # never answered: the replay is killed holding it
        print("holding", flush=True)
    else:
        pending.reply(b"answered")

transport.serve_deferred("strand/sample", handle)
print("ready", flush=True)
while True:
    time.sleep(1)
'''


@dataclass
class Kill:
    kill: int
    outcome: str
    """answered, stranded or no_queryable (module docstring)."""
    after_kill_s: float
    """From the SIGKILL to the end of the client's wait (answer or give-up)."""
    requests: int
    """Requests the client sent in all (1 without --ask-again)."""


@dataclass
class _Wait:
    """What the asking thread saw (set once it returns)."""

    outcome: str = ""
    ended: float = 0.0
    requests: int = 0


def _start_replay(endpoint: str, mode: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, "-c", REPLAY, endpoint, mode],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    if line != "ready":
        proc.kill()
        raise RuntimeError(f"the stand-in replay did not start (printed {line!r})")
    return proc


def _ask(client: Transport, *, timeout_s: float, ask_again_s: float | None,
         out: _Wait) -> None:
    """One request as the learner makes it: asked again after `ask_again_s` if given."""
    deadline = time.monotonic() + timeout_s
    requests = 0
    outcome = "stranded"
    while (remaining := deadline - time.monotonic()) > 0:
        requests += 1
        try:
            client.request(KEY, b"x", timeout_s=min(remaining, ask_again_s or remaining))
            outcome = "answered"
            break
        except TransportTimeout as exc:
            if exc.no_queryable:
                outcome = "no_queryable"
                break
            if ask_again_s is None:
                break
    out.requests, out.ended, out.outcome = requests, time.monotonic(), outcome


def measure(kills: int, *, timeout_s: float, ask_again_s: float | None,
            echo: bool = True) -> list[Kill]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = Transport.open(mode="router", listen=[endpoint])
    client = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=30,
                            rediscover_s=0)  # the bench measures Zenoh, not the reopen
    results: list[Kill] = []
    try:
        for n in range(kills):
            parked = _start_replay(endpoint, "park")
            out = _Wait()
            asker = threading.Thread(target=_ask, args=(client,), daemon=True,
                                     kwargs={"timeout_s": timeout_s, "ask_again_s": ask_again_s,
                                             "out": out})
            asker.start()
            assert parked.stdout is not None
            if parked.stdout.readline().strip() != "holding":
                raise RuntimeError("the stand-in replay never got the request")
            parked.kill()
            killed_at = time.monotonic()
            parked.wait()
            fresh = _start_replay(endpoint, "answer")
            asker.join(timeout_s + 30)
            fresh.kill()
            fresh.wait()
            if not out.outcome:
                raise RuntimeError(f"kill {n}: the client never returned")
            result = Kill(kill=n, outcome=out.outcome,
                          after_kill_s=round(out.ended - killed_at, 3), requests=out.requests)
            results.append(result)
            if echo:
                print(json.dumps(asdict(result)), flush=True)
    finally:
        client.close()
        router.close()
    return results


def summary(results: list[Kill]) -> dict[str, object]:
    outcomes = Counter(r.outcome for r in results)
    answered = [r.after_kill_s for r in results if r.outcome == "answered"]
    return {"kills": len(results), **{k: outcomes.get(k, 0) for k in
                                      ("answered", "stranded", "no_queryable")},
            "longest_wait_s": max((r.after_kill_s for r in results), default=0.0),
            "longest_answered_s": max(answered, default=0.0),
            "asked_again": sum(r.requests > 1 for r in results)}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.faults.stranded_gets",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=100)
    parser.add_argument("--timeout", type=float, default=30.0,
                        help="the request's whole timeout in seconds (default 30)")
    parser.add_argument("--ask-again", type=float, default=None, metavar="S",
                        help="send the request again after S seconds without a reply")
    args = parser.parse_args(argv)
    if args.kills < 1 or args.timeout <= 0 or (args.ask_again is not None
                                                and not 0 < args.ask_again < args.timeout):
        parser.error("--kills must be >= 1, --timeout > 0 and --ask-again in (0, --timeout)")
    results = measure(args.kills, timeout_s=args.timeout, ask_again_s=args.ask_again)
    print(json.dumps({"summary": summary(results), "timeout_s": args.timeout,
                      "ask_again_s": args.ask_again}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
