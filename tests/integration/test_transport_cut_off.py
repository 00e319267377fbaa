"""A client session cut off from its router (hercs.net.rediscovery.CutOff), against real Zenoh
sessions on loopback: the router closed stands for the cut. Requests that find no router for
`cut_off_s` reopen the session with a new Zenoh id, waiting for the router; a stop ends that
wait.

No sleeps stand in for synchronisation: every wait is on an Event or a queue with a timeout.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import pytest

from hercs.net.sessions import _CONNECT_WINDOW_MAX_S
from hercs.net.transport import ConnectAborted, Transport, TransportError
from tests.integration.transport_support import RUN, WAIT_S, echo

pytestmark = pytest.mark.integration

CUT_OFF_S = 0.5
"""Short, to keep the test quick: the transport takes any bound > 0 (the config's floor of
10 s is for real links, where Zenoh's own reconnect should have its chance first)."""
INSERT = f"{RUN}/replay/insert"
TOKEN = f"{RUN}/alive/actor/1"


def ask_until(client: Transport, done: Callable[[], bool]) -> queue.Queue[BaseException | None]:
    """Requests on INSERT from a thread of its own, as an actor's inserter retries, until
    `done()` (then None on the queue) or an exception other than a failed request (put on the
    queue): the reopen a request calls for runs in that request, so it blocks this thread."""
    result: queue.Queue[BaseException | None] = queue.Queue()

    def ask() -> None:
        try:
            while not done():
                try:
                    client.request(INSERT, b"x", timeout_s=0.2)
                except ConnectAborted:
                    raise
                except TransportError:
                    continue
            result.put(None)
        except BaseException as exc:
            result.put(exc)

    threading.Thread(target=ask, daemon=True).start()
    return result


def alive_watch(endpoint: str) -> tuple[Transport, queue.Queue[tuple[str, bool]]]:
    monitor = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=WAIT_S)
    changes: queue.Queue[tuple[str, bool]] = queue.Queue()
    monitor.watch_alive(f"{RUN}/alive/**", lambda key, alive: changes.put((key, alive)))
    return monitor, changes


@dataclass
class Cut:
    """A router on `endpoint` and a client of it with a stop event, a liveliness token and
    one answered request; `cut()` closes the router, `heal()` opens a new one there."""

    endpoint: str
    stop: threading.Event = field(default_factory=threading.Event)
    opened: list[Transport] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.heal()
        self.client = Transport.open(mode="client", connect=[self.endpoint], stop=self.stop,
                                     rediscover_s=0, cut_off_s=CUT_OFF_S)
        self.opened.append(self.client)
        self.client.declare_alive(TOKEN)
        assert self.client.request(INSERT, b"1", timeout_s=WAIT_S) == b"echo:1"

    def heal(self) -> None:
        self.router = Transport.open(mode="router", listen=[self.endpoint])
        self.opened.append(self.router)
        self.router.serve(INSERT, echo)

    def cut(self) -> None:
        self.router.close()


@pytest.fixture
def cut(endpoint: str) -> Iterator[Cut]:
    world = Cut(endpoint)
    yield world
    world.stop.set()  # ends a reopen still waiting
    for transport in reversed(world.opened):
        transport.close()


def test_a_cut_off_client_reopens_with_a_new_id_once_its_router_is_back(
        cut: Cut, log_event: Callable[[str], threading.Event]) -> None:
    reopening = log_event("reopening this process's Zenoh session: no router")
    client = cut.client
    progress: queue.Queue[bytes] = queue.Queue()
    client.subscribe(f"{RUN}/progress", lambda key, payload: progress.put(payload))
    old_id = str(client.session.info.zid())

    cut.cut()  # the client's session has no router from now on
    asking = ask_until(client, lambda: client.reopens > 0)
    assert reopening.wait(4 * WAIT_S), "no reopen was called for"
    assert client.reopens == 0, "the reopen waits for the router"
    cut.heal()
    assert asking.get(timeout=4 * WAIT_S) is None
    assert client.reopens == 1
    assert str(client.session.info.zid()) != old_id, "a new session, so a new Zenoh id"

    # every handle works on the new session
    assert client.request(INSERT, b"2", timeout_s=WAIT_S) == b"echo:2"
    monitor, changes = alive_watch(cut.endpoint)
    cut.opened.append(monitor)
    assert changes.get(timeout=WAIT_S) == (TOKEN, True)
    publisher = monitor.publisher(f"{RUN}/progress", block=True)
    assert publisher.wait_for_subscribers(WAIT_S)
    publisher.put(b"p")
    assert progress.get(timeout=WAIT_S) == b"p"


def test_a_stop_ends_a_reopen_waiting_for_the_router_and_the_old_session_keeps_its_token(
        cut: Cut, log_event: Callable[[str], threading.Event]) -> None:
    """SIGTERM during a cut: the service's stop event ends the reopen at the end of the
    connect window under way (at most `_CONNECT_WINDOW_MAX_S`), with `ConnectAborted`. The
    old session stays, its liveliness token declared on it again: once the router is back,
    Zenoh's own reconnect shows this process alive."""
    reopening = log_event("reopening this process's Zenoh session: no router")
    cut.cut()
    asking = ask_until(cut.client, lambda: False)
    assert reopening.wait(4 * WAIT_S), "no reopen was called for"
    cut.stop.set()
    assert isinstance(asking.get(timeout=_CONNECT_WINDOW_MAX_S + WAIT_S), ConnectAborted)
    assert cut.client.reopens == 0

    cut.heal()
    monitor, changes = alive_watch(cut.endpoint)
    cut.opened.append(monitor)
    assert changes.get(timeout=4 * WAIT_S) == (TOKEN, True)
