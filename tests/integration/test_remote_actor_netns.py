"""A process in another network namespace joins a run through a router it reaches over a veth
pair, as an actor on another host does with `hercs actor --connect tcp/HOST:7447`
(bench.faults.netns; only 10.123.0.1 and .2 are touched). Needs root and `ip`; skipped with the
reason otherwise. Every wait is on a queue, a Zenoh event or a process exit, with a timeout.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from importlib.util import find_spec
from pathlib import Path

import pytest
import yaml

from bench.faults.netns import Host, hosts, problem
from hercs.apps.launch.router import free_port, open_router
from hercs.config import HercsConfig, SecurityConfig, apply_overrides
from hercs.net.transport import PendingReply, Transport
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.wire.validation import parse_message

pytestmark = pytest.mark.integration

SUBNET = "10.123"
WAIT_S = 20.0


@pytest.fixture(scope="module")
def netns() -> Iterator[Host]:
    """A namespace reached over a veth pair: host 10.123.0.1/24, namespace 10.123.0.2/24."""
    if (why := problem(SUBNET, faults=False)) is not None:
        pytest.skip(why)
    try:
        with hosts(1, subnet=SUBNET, first=0) as (host,):
            yield host
    except RuntimeError as exc:
        if "netns add" not in str(exc):
            raise
        pytest.skip(f"cannot create a network namespace here: {exc}")


@pytest.fixture
def router(netns: Host) -> Iterator[tuple[Transport, str]]:
    """A router listening only on the host end of the veth pair."""
    endpoint = f"tcp/{netns.host_ip}:{free_port(netns.host_ip)}"
    # a private veth pair nobody else reaches: plain TCP on purpose (the secured set-up is
    # tests/fault/test_security.py); a non-loopback listen address needs the explicit opt-in
    transport = open_router([endpoint], SecurityConfig(allow_insecure=True))
    yield transport, endpoint
    transport.close()


def in_netns(host: Host, argv: list[str], log: Path) -> subprocess.Popen[bytes]:
    with log.open("wb") as out:
        return subprocess.Popen(host.exec_argv(argv), stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL)


def get(q: queue.Queue, what: str) -> object:
    try:
        return q.get(timeout=WAIT_S)
    except queue.Empty:
        raise AssertionError(f"timed out after {WAIT_S} s waiting for {what}") from None


CLIENT = textwrap.dedent('''
    import os, sys
    from hercs.net.transport import Transport
    endpoint, key, alive_key = sys.argv[1:4]
    with Transport.open(mode="client", connect=[endpoint], connect_timeout_s=10) as t:
        t.declare_alive(alive_key)
        netns = os.readlink("/proc/self/ns/net").encode()
        print(t.request(key, netns, timeout_s=10).decode(), flush=True)
        sys.stdin.read()  # hold the token until the test closes stdin
''')


def test_client_in_another_namespace_reaches_the_router(netns: Host, tmp_path: Path,
                                                        router: tuple[Transport, str]) -> None:
    transport, endpoint = router
    keys = RunKeys("netns")
    requests: queue.Queue[bytes] = queue.Queue()
    alive: queue.Queue[tuple[str, bool]] = queue.Queue()

    def answer(payload: bytes) -> bytes:
        requests.put(payload)
        return b"pong " + payload

    transport.serve(keys.config, answer)
    transport.watch_alive(keys.all_alive, lambda key, up: alive.put((key, up)))
    token = keys.alive("actor", "netns-1")
    client = subprocess.Popen(
        netns.exec_argv([sys.executable, "-c", CLIENT, endpoint, keys.config, token]),
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert get(alive, "the namespaced client's liveliness token") == (token, True)
        their_netns = get(requests, "the namespaced client's request")
        assert their_netns != os.readlink("/proc/self/ns/net").encode(), "not namespaced"
        out, err = client.communicate(b"", timeout=WAIT_S)  # closes stdin: the client exits
        assert client.returncode == 0, err.decode()
        assert out.decode().strip() == "pong " + their_netns.decode()
        assert get(alive, "the token to vanish") == (token, False)
    finally:
        if client.poll() is None:
            client.kill()
            client.wait()


@pytest.mark.skipif(find_spec("hercs.actors.actor_shell") is None,
                    reason="hercs actor not written yet")
def test_hercs_actor_in_another_namespace_gets_its_inserts_acked(
        netns: Host, tmp_path: Path, router: tuple[Transport, str]) -> None:
    """`hercs actor --connect … --run …` from the namespace: the test plays the replay (serves
    the run's config, acks inserts)."""
    transport, endpoint = router
    run = "netns-actor"
    keys = RunKeys(run)
    served: HercsConfig = apply_overrides(HercsConfig(), [
        f"run.name={run}", "run.method=her", "task.name=reach", "ddpg.hidden_size=64",
        "transport.connect=[tcp/127.0.0.1:1]",  # the actor must keep its own endpoint
    ])
    inserts: queue.Queue[pb.Episode] = queue.Queue()
    alive: queue.Queue[tuple[str, bool]] = queue.Queue()

    def ack(pending: PendingReply) -> None:
        msg = parse_message(pending.payload, pb.Episode, max_bytes=8 << 20)
        inserts.put(msg)
        pending.reply(pb.InsertAck(schema_version=SCHEMA_VERSION, actor_id=msg.actor_id,
                                   seq=msg.seq, episode_id=inserts.qsize()).SerializeToString())

    transport.serve(keys.config,
                    lambda _: yaml.safe_dump(served.to_dict(), sort_keys=False).encode())
    transport.serve_deferred(keys.insert, ack)
    transport.watch_alive(keys.all_alive, lambda key, up: alive.put((key, up)))
    log = tmp_path / "actor.log"
    actor = in_netns(netns, [sys.executable, "-m", "hercs.apps.cli", "actor", "--connect", endpoint,
                             "--run", run, "--id", "far-actor"], log)
    try:
        assert get(alive, "the actor's liveliness token") == (keys.alive("actor", "far-actor"),
                                                              True)
        episodes = [get(inserts, f"insert {i}") for i in range(2)]
        # On the wire the actor is `<--id>@<incarnation>`, one incarnation for the process.
        assert [(e.actor_id.partition("@")[0], e.seq, e.task, e.run) for e in episodes] == [
            ("far-actor", 0, "reach", run), ("far-actor", 1, "reach", run)]
        assert len({e.actor_id for e in episodes}) == 1
        actor.send_signal(signal.SIGTERM)
        assert actor.wait(timeout=WAIT_S) == 0, log.read_text()
    finally:
        if actor.poll() is None:
            actor.kill()
            actor.wait()
        print(log.read_text())
