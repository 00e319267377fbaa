"""Security on loopback with certificates made in the test: mutual TLS keeps out clients
without a certificate of the run's CA; user/password keeps out wrong passwords; access
control lets each role use only its own keys; a router reachable from other hosts is refused
without TLS; a whole `hercs up` run works with everything switched on."""

from __future__ import annotations

import queue
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from hercs.apps.deploy.certs import make_certs
from hercs.apps.launch.router import free_port, open_router
from hercs.config import SecurityConfig
from hercs.net.security import listen_problem, zenoh_settings
from hercs.net.transport import RouterUnreachable, Transport, TransportError
from hercs.proto.keys import RunKeys
from hercs.run.rundir import RunDir

pytestmark = [pytest.mark.integration, pytest.mark.timeout(300)]

KEYS = RunKeys("sec")
CONNECT_S = 3.0


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("certs")
    make_certs(out, credentials=True)
    return out


@pytest.fixture(scope="module")
def rogue(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Certificates with the right names from another CA."""
    out = tmp_path_factory.mktemp("rogue")
    make_certs(out)
    return out


def _security(certs: Path, *, credentials: bool = True) -> SecurityConfig:
    return SecurityConfig(tls_ca=str(certs / "ca.pem"), tls_cert=str(certs / "{role}.pem"),
                          tls_key=str(certs / "{role}.key"),
                          credentials=str(certs / "credentials.txt") if credentials else "")


@pytest.fixture
def secured(certs: Path) -> Iterator[str]:
    """A router with mutual TLS, passwords and access control; yields its endpoint."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    router = open_router([endpoint], _security(certs))
    yield endpoint
    router.close()


class Clients:
    def __init__(self, endpoint: str, security: SecurityConfig) -> None:
        self.endpoint, self.security, self.opened = endpoint, security, []

    def open(self, role: str, security: SecurityConfig | None = None) -> Transport:
        settings = zenoh_settings(security or self.security, mode="client", role=role,
                                  endpoints=[self.endpoint])
        transport = Transport.open(mode="client", connect=[self.endpoint],
                                   connect_timeout_s=CONNECT_S, settings=settings)
        self.opened.append(transport)
        return transport


@pytest.fixture
def clients(secured: str, certs: Path) -> Iterator[Clients]:
    made = Clients(secured, _security(certs))
    yield made
    for transport in reversed(made.opened):
        transport.close()


# -- who may connect ----------------------------------------------------------------------


def test_clients_without_a_valid_certificate_or_password_cannot_connect(
        clients: Clients, certs: Path, rogue: Path, tmp_path: Path) -> None:
    no_cert = SecurityConfig(credentials=str(certs / "credentials.txt"))
    with pytest.raises(RouterUnreachable):  # TLS without a certificate of its own
        clients.open("actor", no_cert)
    plain = f"tcp/{clients.endpoint.removeprefix('tls/')}"
    with pytest.raises(RouterUnreachable):
        Transport.open(mode="client", connect=[plain], connect_timeout_s=CONNECT_S)
    with pytest.raises(RouterUnreachable):  # the right name and password, another CA
        clients.open("actor", SecurityConfig(
            tls_ca=str(certs / "ca.pem"), tls_cert=str(rogue / "actor.pem"),
            tls_key=str(rogue / "actor.key"), credentials=str(certs / "credentials.txt")))
    wrong = tmp_path / "wrong.txt"
    wrong.write_text("actor:not-the-password\n")
    with pytest.raises(RouterUnreachable):
        clients.open("actor", SecurityConfig(**{**vars(_security(certs)),
                                                "credentials": str(wrong)}))
    clients.open("actor")  # the real actor gets in


# -- what each role may do ----------------------------------------------------------------


def _settle(transport: Transport) -> None:
    """Returns once the router has handled everything `transport` sent before: a query
    round trip on the same session (its messages reach the router in order)."""
    transport.request(KEYS.config, b"", timeout_s=10)


@pytest.fixture
def run(clients: Clients) -> dict[str, Transport]:
    """The real roles of a run, each with its own certificate, and a replay serving the
    config (for `_settle`) and inserts."""
    roles = {role: clients.open(role) for role in
             ("replay", "learner", "clusterer", "evaluator", "actor")}
    roles["replay"].serve(KEYS.config, lambda _: b"config")
    roles["replay"].serve(KEYS.insert, lambda payload: b"ack:" + payload)
    return roles


def _subscribe(transport: Transport, key: str) -> queue.Queue[bytes]:
    got: queue.Queue[bytes] = queue.Queue()
    transport.subscribe(key, lambda _, payload: got.put(payload))
    return got


@pytest.mark.parametrize(("key", "owner", "reader"), [
    (KEYS.weights, "learner", "evaluator"),
    (KEYS.cluster_model, "clusterer", "replay"),
    (KEYS.eval_result, "evaluator", "learner"),
])
def test_an_actor_cannot_publish_what_another_role_owns(run: dict[str, Transport], key: str,
                                                        owner: str, reader: str) -> None:
    got = _subscribe(run[reader], key)
    owner_pub = run[owner].publisher(key, block=True)
    owner_pub.wait_for_subscribers(10)
    run["actor"].session.put(key, b"forged")  # an actor host that was taken over
    _settle(run["actor"])  # the forged put has been routed (or dropped) by now
    owner_pub.put(b"genuine")
    assert got.get(timeout=10) == b"genuine", "the forged message reached the reader"
    assert got.empty()


def test_an_actor_cannot_serve_the_replays_queries(clients: Clients,
                                                   run: dict[str, Transport]) -> None:
    fake = clients.open("actor")
    fake.serve(KEYS.sample, lambda _: b"fake batch")
    fake.serve(KEYS.insert, lambda _: b"fake ack")
    _settle(fake)
    with pytest.raises(TransportError):  # the learner's sample request reaches no fake
        run["learner"].request(KEYS.sample, b"req", timeout_s=2)
    for n in range(20):  # every insert is answered by the real replay
        assert run["actor"].request(KEYS.insert, b"%d" % n, timeout_s=10) == b"ack:%d" % n


def test_an_authenticated_actor_inserts_and_reads_weights(run: dict[str, Transport]) -> None:
    assert run["actor"].request(KEYS.insert, b"episode", timeout_s=10) == b"ack:episode"
    got = _subscribe(run["actor"], KEYS.weights)
    pub = run["learner"].publisher(KEYS.weights, block=True)
    pub.wait_for_subscribers(10)
    pub.put(b"weights v1")
    assert got.get(timeout=10) == b"weights v1"


@pytest.mark.parametrize(("key", "owner", "joiner"), [
    (KEYS.weights, "learner", "actor"),
    (KEYS.weights, "learner", "evaluator"),
    (KEYS.progress, "learner", "actor"),
    (KEYS.cluster_model, "clusterer", "replay"),
], ids=["weights-actor", "weights-evaluator", "progress-actor", "model-replay"])
def test_a_late_joiner_gets_the_latest_value_through_access_control(
        clients: Clients, run: dict[str, Transport], key: str, owner: str,
        joiner: str) -> None:
    """A restarted actor (or replay) must find the last weights (model) at once, not at the
    next put: a lone actor restarted while the learner waits for its episodes would otherwise
    never act with weights, and its episodes would be refused as stale for ever. The cache's
    reply carries the plain key, which access control must let through."""
    pub = run[owner].publisher(key, latest=True, block=True)
    pub.put(b"v1")  # into the publisher's own cache at once
    late = clients.open(joiner)
    got: queue.Queue[bytes] = queue.Queue()
    late.subscribe(key, lambda _, payload: got.put(payload), latest=True)
    assert got.get(timeout=10) == b"v1"


# -- exposure -------------------------------------------------------------------------------


def test_a_router_reachable_from_other_hosts_needs_tls(certs: Path) -> None:
    exposed = [f"tcp/0.0.0.0:{free_port()}"]
    assert "no authentication" in (listen_problem(SecurityConfig(), exposed) or "")
    assert listen_problem(SecurityConfig(allow_insecure=True), exposed) is None
    assert listen_problem(SecurityConfig(), ["tcp/127.0.0.1:7447", "tcp/[::1]:7447"]) is None
    assert listen_problem(_security(certs), [f"tls/0.0.0.0:{free_port()}"]) is None
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "router", "--listen",
                           exposed[0]], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "--tls-ca" in done.stderr and "allow_insecure" in done.stderr


def test_hercs_up_with_tls_passwords_and_access_control(certs: Path, tmp_path: Path) -> None:
    """A whole run (router, replay, clusterer, learner, evaluator, actor) with every process
    on its own certificate and password: it trains its epoch and finishes."""
    cmd = [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--method", "her-cs",
           "--epochs", "1", "--run", "secure", "--run-dir", str(tmp_path),
           "--listen", f"tls/127.0.0.1:{free_port()}", "--tls-dir", str(certs),
           "--credentials", str(certs / "credentials.txt"),
           "--set", "training.cycles_per_epoch=2", "--set", "training.eval_episodes=2",
           "--set", "training.episodes_per_cycle=2", "--set", "training.minibatches_per_cycle=2",
           "--set", "cluster.fgb_size=8", "--set", "cluster.k=2"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "epoch 1/1  success" in done.stdout
    rows = RunDir(tmp_path / "secure").metrics.read_text().splitlines()
    assert len(rows) == 2 and int(rows[1].split(",")[2]) > 0, "episodes were inserted"
