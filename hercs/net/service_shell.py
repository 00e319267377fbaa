"""What every service process shares: the one entry protocol (`service_main`), its Zenoh
transport, liveliness token, stop event, metrics publishing and rate-limited warnings.

A service's `run(config, *, ident)` is `service_main(role=…, config=…, ident=…, body=…)`;
`body(runtime)` declares the service's entities through `runtime.transport`, works until
`runtime.stop` is set and returns the exit status.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import socket
import threading
import time
import uuid
from collections.abc import Callable, Mapping

import yaml

from hercs.config import HercsConfig
from hercs.errors import ConfigError, Diverged, Unreachable
from hercs.net.backoff import Backoff
from hercs.net.security import zenoh_settings
from hercs.net.signals import StopSignals
from hercs.net.threads import single_threaded_numerics
from hercs.net.transport import ConnectAborted, Transport, TransportError
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import ROOT, RunKeys

log = logging.getLogger(__name__)

CONFIG_REQUEST_TIMEOUT_S = 10.0
CONFIG_RETRY_MAX_S = 2.0
_CONFIG_LOG_EVERY_S = 10.0


def default_ident() -> str:
    """An id unique across hosts and restarts: host name plus a short uuid (compose-scaled
    containers have distinct host names)."""
    host = "".join(c if c.isalnum() or c in "-_" else "-" for c in socket.gethostname())
    return f"{host or 'host'}-{uuid.uuid4().hex[:6]}"


def setup_logging(role: str) -> None:
    logging.basicConfig(
        level=os.environ.get("HERCS_LOG", "INFO"),
        format=f"%(asctime)s {role} %(levelname)s %(name)s: %(message)s",
    )


EXIT_OK = 0
EXIT_FAILED = 1
"""The service failed: an unexpected exception (logged with its traceback) or a fault it
reports itself."""
EXIT_CONFIG = 2
"""The configuration cannot be used (`ConfigError`): retrying the same command will not help."""
EXIT_UNREACHABLE = 3
"""The router, or the run's replay, did not answer within `transport.wait_s` (`Unreachable`)."""
EXIT_DIVERGED = 4
"""The learner's training diverged (`Diverged`: a loss or a weight not finite); a restart
would resume from the checkpoint into the same divergence, so `hercs up` stops the run."""


THREAD_JOIN_S = 5.0
"""How long a closing service waits for its own threads, in all."""


def start_supervised(target: Callable[[], None], *, name: str,
                     on_crash: Callable[[str, BaseException], None]) -> threading.Thread:
    """A daemon thread running `target`; an exception escaping it is logged with its
    traceback and handed to `on_crash(name, exc)` (e.g. `ServiceRuntime.crashed`)."""

    def run() -> None:
        try:
            target()
        except BaseException as exc:
            log.exception("thread %s died", name)
            on_crash(name, exc)

    thread = threading.Thread(target=run, name=name, daemon=True)
    thread.start()
    return thread


class ServiceRuntime:
    """One service process: transport (client of the router), liveliness token, stop event.

    `stop` is set by `service_main` when a stop signal arrives; every wait of the service
    watches it, the wait for the router included (it then raises `ConnectAborted`).
    """

    def __init__(self, *, config: HercsConfig, role: str, ident: str | None = None,
                 stop: threading.Event | None = None) -> None:
        if not config.run.name:
            raise ConfigError("run.name: got '', a service needs the run's name (--run RUN)")
        self.config = config
        self.role = role
        self.ident = ident or default_ident()
        self.keys = RunKeys(config.run.name)
        self.stop = stop if stop is not None else threading.Event()
        self.failed: str | None = None
        """Why the service must exit non-zero although its body returned (a dead thread)."""
        settings = zenoh_settings(config.security, mode="client", role=role,
                                  endpoints=config.transport.connect)
        self.transport = Transport.open(mode="client", connect=config.transport.connect,
                                        connect_timeout_s=config.transport.wait_s or None,
                                        stop=self.stop, settings=settings,
                                        rediscover_s=config.transport.rediscover_s,
                                        cut_off_s=config.transport.cut_off_s)
        self.alive = self.transport.declare_alive(self.keys.alive(role, self.ident))
        self._metrics = self.transport.publisher(self.keys.metrics(role))
        self._metrics_step = 0
        self._threads: list[threading.Thread] = []

    def start_thread(self, target: Callable[[], None], *, name: str) -> threading.Thread:
        """Run `target` on a daemon thread that may not die silently: an exception is logged,
        recorded in `failed` and stops the service, which then exits non-zero (the launcher
        sees it and restarts it) instead of running on with a part missing."""
        thread = start_supervised(target, name=name, on_crash=self.crashed)
        self._threads.append(thread)
        return thread

    def crashed(self, name: str, exc: BaseException) -> None:
        """A part of this service died: stop, and make the exit status say so."""
        self.failed = self.failed or f"thread {name} died: {type(exc).__name__}: {exc}"
        self.stop.set()

    def publish_metrics(self, values: Mapping[str, float], step: int | None = None) -> None:
        self._metrics_step = self._metrics_step + 1 if step is None else step
        msg = pb.Metrics(schema_version=SCHEMA_VERSION, service=f"{self.role}/{self.ident}",
                         step=self._metrics_step,
                         values={k: float(v) for k, v in values.items()})
        self._metrics.put(msg.SerializeToString())

    def close(self) -> None:
        """Stop the service's threads, close the transport, and wait (up to
        `THREAD_JOIN_S` in all) for the threads to end, so that none is still inside a
        Zenoh or torch call while the interpreter exits (a learner that had finished its
        epochs once aborted at exit with its prefetch thread retrying on a closed session)."""
        self.stop.set()
        self.transport.close()  # ends the threads' pending requests and receives
        deadline = time.monotonic() + THREAD_JOIN_S
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))
            if thread.is_alive():
                log.warning("thread %s still running at exit", thread.name)

    def __enter__(self) -> ServiceRuntime:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


ServiceBody = Callable[[ServiceRuntime], int]
"""A service's work: runs until `runtime.stop` is set (or the work is done); returns the exit
status."""


def service_main(*, role: str, config: HercsConfig, body: ServiceBody,
                 ident: str | None = None) -> int:
    """The entry protocol every service process (`hercs <role>`) follows; returns its exit
    status. Call it on the main thread.

    - Logging is set up for `role`; numerics run on one thread (`hercs.net.threads`).
    - SIGINT and SIGTERM are caught with `StopSignals`: the handler only records the signal
      and the main thread, woken, sets `runtime.stop` (setting an Event inside a handler can
      deadlock on the Event's own lock).
    - The runtime is opened and `body` runs on a worker thread, so that a stop signal also
      ends the wait for an unreachable router (exit 0: nothing had started).
    - Exit status: what `body` returns; `EXIT_CONFIG` (2) for a `ConfigError`, from the
      runtime (e.g. no run name) or from `body`; `EXIT_UNREACHABLE` (3) when the router or
      the run did not answer within `transport.wait_s`; `EXIT_DIVERGED` (4) for `Diverged`
      (the learner's numbers are no longer finite); `EXIT_FAILED` (1) for any other exception,
      logged with its traceback, and for a supervised thread that died
      (`runtime.start_thread`) even if `body` then returned 0. The runtime is closed in
      every case.
    """
    setup_logging(role)
    single_threaded_numerics()
    stop = threading.Event()
    status: list[int] = []
    done = threading.Event()

    with StopSignals() as signals:
        def work() -> None:
            try:
                with ServiceRuntime(config=config, role=role, ident=ident,
                                    stop=stop) as runtime:
                    code = int(body(runtime))
                    if runtime.failed is not None:
                        log.error("hercs %s: %s; exiting with status %d", role, runtime.failed,
                                  EXIT_FAILED)
                        code = code or EXIT_FAILED
                    status.append(code)
            except ConfigError as exc:
                log.error("hercs %s: invalid configuration: %s", role, exc)
                status.append(EXIT_CONFIG)
            except Unreachable as exc:
                log.error("hercs %s: %s", role, exc)
                status.append(EXIT_UNREACHABLE)
            except Diverged as exc:
                log.error("hercs %s: %s; exiting with status %d", role, exc, EXIT_DIVERGED)
                status.append(EXIT_DIVERGED)
            except ConnectAborted as exc:  # stopped before the router was ever reached
                log.info("hercs %s: %s", role, exc)
                status.append(EXIT_OK)
            except Exception:
                log.exception("hercs %s: failed", role)
                status.append(EXIT_FAILED)
            finally:
                done.set()  # before the wake-up: the main thread re-checks it after each one
                signals.wake()

        worker = threading.Thread(target=work, name=f"{role}-main", daemon=True)
        worker.start()
        # Not `worker.is_alive()`: the worker is still alive for a moment after its wake(),
        # and a wait entered then would never return. `done` is set before the wake(), and a
        # wake() sent before a wait is still pending in the socket, so there is no race.
        while not done.is_set() and not signals.stop_requested:
            signals.wait(None)
        if signals.stop_requested:
            log.info("%s: got signal %d, stopping", role, signals.received[0])
            stop.set()
        worker.join()
    return status[0] if status else EXIT_FAILED


def fetch_run_config(transport: Transport, run: str, *,
                     timeout_s: float = CONFIG_REQUEST_TIMEOUT_S) -> HercsConfig:
    """The resolved config of a running run, served by its replay (for actors on other hosts
    that were given only `--connect` and `--run`)."""
    raw = transport.request(RunKeys(run).config, b"", timeout_s=timeout_s)
    return HercsConfig.from_dict(yaml.safe_load(raw.decode()))


class RunUnreachable(Unreachable):
    """The router answered but no replay of the run served its config within
    `transport.wait_s`."""


def known_runs(transport: Transport) -> list[str]:
    """The runs whose replay is alive on this router now (from their liveliness tokens)."""
    runs = set()
    for key in transport.alive_keys(f"{ROOT}/*/alive/replay/*"):
        parts = key.split("/")
        if len(parts) == 5:
            runs.add(parts[1])
    return sorted(runs)


def _runs_text(runs: list[str]) -> str:
    return (f"runs with a replay on this router: {', '.join(runs)}" if runs
            else "no run has a replay on this router")


def join_run(runtime: ServiceRuntime, local: HercsConfig, *,
             keep: tuple[str, ...] = ("transport", "security")) -> HercsConfig | None:
    """The run's resolved config from its replay, with `local`'s `keep` sections (how this
    process reaches the router, and e.g. the live view's own `view` section).

    Retries (backoff up to `CONFIG_RETRY_MAX_S`) until the replay answers, logging every 10 s
    what it waits for and which runs the router knows; None if `runtime.stop` is set first.
    Raises `RunUnreachable` after `transport.wait_s` (0: never), and `ConfigError` for a
    config this version of hercs cannot read (retrying would not help).
    """
    run = local.run.name
    wait_s = local.transport.wait_s
    backoff = Backoff(0.1, CONFIG_RETRY_MAX_S)
    start = time.monotonic()
    next_log = start
    while not runtime.stop.is_set():
        timeout_s = CONFIG_REQUEST_TIMEOUT_S
        if wait_s:
            timeout_s = max(0.1, min(timeout_s, start + wait_s - time.monotonic()))
        try:
            remote = fetch_run_config(runtime.transport, run, timeout_s=timeout_s)
        except TransportError as exc:  # no replay yet, restarting, or a timeout: retry
            now = time.monotonic()
            if wait_s and now - start >= wait_s:
                raise RunUnreachable(
                    f"run {run!r}: no replay served its config within transport.wait_s = "
                    f"{wait_s:g} s ({_runs_text(known_runs(runtime.transport))}); check "
                    "--run, or start the run first") from None
            if now >= next_log:
                log.info("waiting for run %r's replay to serve its config (%.0f s so far; %s): "
                         "%s", run, now - start, _runs_text(known_runs(runtime.transport)), exc)
                next_log = now + _CONFIG_LOG_EVERY_S
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise ConfigError(f"run {run!r}: the replay served a config that is not YAML "
                              f"({exc})") from None
        else:
            if remote.run.name != run:
                log.warning("run %r's replay serves a config named %r; keeping %r (the keys "
                            "this process uses)", run, remote.run.name, run)
            kept = {name: getattr(local, name) for name in keep}
            return dataclasses.replace(
                remote, run=dataclasses.replace(remote.run, name=run), **kept)
        backoff.wait(runtime.stop)
    return None
