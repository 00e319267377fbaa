"""The system under test: an embedded Zenoh router on a free loopback port, an observing
client, `python -m hercs.apps.cli <role>` children (started and stopped with the launcher's
hercs/apps/launch/child_process.py), the synthetic actors, and the measurements so far."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from bench.common import REPO
from bench.perf.throughput import BenchError, say
from bench.perf.throughput.plan import (
    EPISODE_POOL,
    MAX_REPLY_BYTES,
    MEMORY_FIELDS,
    NO_SCENE,
    READY_TIMEOUT_S,
    RUN,
    SEED,
    STOP_GRACE_S,
    Plan,
)
from bench.perf.throughput.rates import Alternation
from bench.perf.throughput.synthetic import SyntheticFleet, episode_pool
from bench.perf.throughput.throughput_report import Figure, parse_proc_status_kib
from hercs.apps.launch.child_process import log_tail, service_argv, signal_group, start_child
from hercs.apps.launch.router import free_port, open_router
from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.net.transport import Transport
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.run.rundir import RunDir
from hercs.wire.validation import parse_message


def free_endpoint() -> str:
    """A loopback TCP endpoint nothing listens on; never 7447 (other runs use it)."""
    port = free_port()
    while port == 7447:
        port = free_port()
    return f"tcp/127.0.0.1:{port}"


class Child:
    """One service process of the run (hercs/apps/launch/child_process.py: `python -m hercs.apps.cli
    <role>` in its own process group, killed if this process dies), with what the phases read of
    it."""

    def __init__(self, *, role: str, ident: str, config_path: Path, log_dir: Path) -> None:
        self.role = role
        self.ident = ident
        self.log_path = log_dir / f"{ident}.log"
        self.proc = start_child(service_argv(role, ident, config_path), log_path=self.log_path,
                                cwd=REPO)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def check_alive(self) -> None:
        code = self.proc.poll()
        if code is not None:
            raise BenchError(f"{self.role} {self.ident} exited with {code}; end of its log "
                             f"{self.log_path}:\n{self.log_tail()}")

    def memory_mib(self) -> dict[str, float]:
        """`MEMORY_FIELDS` of /proc/<pid>/status, in MiB."""
        self.check_alive()
        text = Path(f"/proc/{self.pid}/status").read_text()
        return {name: parse_proc_status_kib(text, name) / 1024 for name in MEMORY_FIELDS}

    def cpu_seconds(self) -> float:
        """User + system CPU time the process has used so far (its threads included)."""
        self.check_alive()
        fields = Path(f"/proc/{self.pid}/stat").read_text().rpartition(")")[2].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def pause(self) -> None:
        """SIGSTOP the process group: it uses no CPU until `resume`."""
        self.check_alive()
        self._signal_group(signal.SIGSTOP)

    def resume(self) -> None:
        self._signal_group(signal.SIGCONT)

    def log_tail(self, lines: int = 25) -> str:
        return "\n".join(log_tail(self.log_path, lines))

    def _signal_group(self, sig: int) -> None:
        signal_group(self.proc, sig)

    def stop(self, grace_s: float = STOP_GRACE_S) -> int:
        """SIGTERM to the group, wait `grace_s`, then SIGKILL; returns the exit code."""
        if self.proc.poll() is None:
            self._signal_group(signal.SIGTERM)
            self._signal_group(signal.SIGCONT)  # a paused child handles SIGTERM only now
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                say(f"{self.role} {self.ident} ignored SIGTERM for {grace_s:g} s; killing it")
        self._signal_group(signal.SIGKILL)  # the child, if it hung, and anything it forked
        self.proc.wait()
        return int(self.proc.returncode)


class Latest:
    """The newest value of a stream, with a wait for a condition on it."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._value: Any = None

    def set(self, value: Any) -> None:
        with self._cond:
            self._value = value
            self._cond.notify_all()

    def clear(self) -> None:
        self.set(None)

    def wait_for(self, pred: Callable[[Any], bool], timeout_s: float) -> Any:
        """The first value satisfying `pred` (None never does), or None after `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._value is None or not pred(self._value):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(min(remaining, 0.5))
            return self._value


class Arrivals:
    """(arrival time, value) of every sample of a stream, appended from a Zenoh thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: list[tuple[float, Any]] = []

    def add(self, value: Any) -> None:
        now = time.monotonic()
        with self._lock:
            self._items.append((now, value))

    def snapshot(self) -> list[tuple[float, Any]]:
        with self._lock:
            return list(self._items)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()

    def wait_count(self, pred: Callable[[Any], bool], count: int, *, timeout_s: float,
                   alive: Child) -> list[tuple[float, Any]]:
        """Wait until `count` items satisfy `pred`; BenchError (with `alive`'s log) if not."""
        deadline = time.monotonic() + timeout_s
        while True:
            items = [(t, v) for t, v in self.snapshot() if pred(v)]
            if len(items) >= count:
                return items
            alive.check_alive()
            if time.monotonic() > deadline:
                raise BenchError(f"only {len(items)} of {count} expected messages within "
                                 f"{timeout_s:g} s; end of {alive.log_path}:\n{alive.log_tail()}")
            time.sleep(0.05)


class Harness:
    """The run: router, an observing client, the children, and the measurements so far."""

    def __init__(self, *, plan: Plan, workdir: Path) -> None:
        self.plan = plan
        self.workdir = workdir
        self.log_dir = RunDir(workdir).logs
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.endpoint = free_endpoint()
        self.keys = RunKeys(RUN)
        self.figures: list[Figure] = []
        self.details: dict[str, Any] = {}
        self.phase_wall_s: dict[str, float] = {}
        self.children: list[Child] = []
        self.status = Latest()
        self.headers = Arrivals()
        self.weights = Arrivals()
        self.configs = {m: self._write_config(m) for m in plan.methods}
        # A replay of its own (own log folder) for the inserts without scenes.
        self.configs[NO_SCENE] = self._write_config("her", name=NO_SCENE, extra=[
            "replay.log_scene=false", f"run.run_dir={self.workdir / 'runs-no-scene'}"])
        self.spec = self.configs[plan.methods[0]][0].task.spec
        self.pool = episode_pool(self.spec, EPISODE_POOL)
        self.router: Transport | None = None
        self.observer: Transport | None = None
        self._fleet: SyntheticFleet | None = None

    # -- set-up ----------------------------------------------------------------------------
    def _write_config(self, method: str, *, name: str | None = None,
                      extra: Sequence[str] = ()) -> tuple[HercsConfig, Path]:
        p = self.plan
        config = apply_overrides(HercsConfig(), [
            f"run.name={RUN}", f"run.run_dir={self.workdir / 'runs'}", f"run.seed={SEED}",
            "task.name=push", f"run.method={method}", "replay.free_run=true",
            "training.max_policy_lag=-1",  # synthetic actors act with no weights version
            f"replay.buffer_transitions={p.buffer_transitions}",
            f"training.minibatches_per_cycle={p.minibatches_per_cycle}",
            "training.epochs=1000000",  # the learner runs until stopped
            f"actor.envs_per_process={p.actor_envs}",
            f"transport.connect=[{self.endpoint}]", f"transport.listen=[{self.endpoint}]",
            *extra,
        ])
        path = self.workdir / f"config-{name or method}.yaml"
        save_yaml(config, path)
        return config, path

    def __enter__(self) -> Harness:
        self.router = open_router([self.endpoint])
        self.observer = Transport.open(mode="client", connect=[self.endpoint],
                                       connect_timeout_s=30.0)
        self.observer.subscribe(self.keys.status, self._on_status, drop_oldest=True,
                                capacity=4)
        self.observer.subscribe(self.keys.inserted, self._on_header, capacity=4096)
        self.observer.subscribe(self.keys.weights, self._on_weights, capacity=256)
        return self

    def __exit__(self, *exc: object) -> None:
        for child in reversed(self.children):
            child.stop()
        self.children.clear()
        if self._fleet is not None:
            self._fleet.close()
        if self.observer is not None:
            self.observer.close()
        if self.router is not None:
            self.router.close()

    def _on_status(self, key: str, raw: bytes) -> None:
        self.status.set(pb.ReplayStatus.FromString(raw))

    def _on_header(self, key: str, raw: bytes) -> None:
        self.headers.add(pb.EpisodeHeader.FromString(raw).actor_id)

    def _on_weights(self, key: str, raw: bytes) -> None:
        self.weights.add(int(parse_message(raw, pb.Weights, max_bytes=MAX_REPLY_BYTES).version))

    @property
    def fleet(self) -> SyntheticFleet:
        """The synthetic actors (as many as the largest insert level), opened on first use."""
        if self._fleet is None:
            self._fleet = SyntheticFleet(size=max(self.plan.insert_actor_counts),
                                         endpoint=self.endpoint, pool=self.pool,
                                         task=self.spec.name)
        return self._fleet

    @property
    def client(self) -> Transport:
        assert self.observer is not None, "use Harness as a context manager"
        return self.observer

    # -- children ----------------------------------------------------------------------------
    def start(self, role: str, ident: str, method: str = "her") -> Child:
        child = Child(role=role, ident=ident, config_path=self.configs[method][1],
                      log_dir=self.log_dir)
        self.children.append(child)
        say(f"started {role} {ident} (pid {child.pid}), log {child.log_path}")
        return child

    def stop(self, child: Child) -> None:
        code = child.stop()
        self.children.remove(child)
        if code not in (0, -signal.SIGTERM):
            say(f"{child.role} {child.ident} exited with {code}; see {child.log_path}")

    def wait_status(self, pred: Callable[[pb.ReplayStatus], bool], *, what: str,
                    replay: Child, timeout_s: float = READY_TIMEOUT_S) -> pb.ReplayStatus:
        """The first ReplayStatus satisfying `pred`, checking that the replay lives."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            replay.check_alive()
            status = self.status.wait_for(pred, min(2.0, deadline - time.monotonic()))
            if status is not None:
                return status
        raise BenchError(f"no ReplayStatus with {what} within {timeout_s:g} s; end of "
                         f"{replay.log_path}:\n{replay.log_tail()}")

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        say(f"phase {name}")
        start = time.monotonic()
        try:
            yield
        finally:
            self.phase_wall_s[name] = round(time.monotonic() - start, 1)

    # -- alternation ---------------------------------------------------------------------------
    def alternate(self, child: Child, *, rounds: int, slice_s: float,
                  reference: Callable[[float], tuple[float, float, float]]) -> Alternation:
        """Reference and system in turns: `reference(slice_s)` runs here while `child` is
        paused, then `child` runs alone for `slice_s`; `rounds` times, and one more reference
        slice at the end, so each system slice sits between two reference slices.

        Short alternating slices make both sides see the same background load, which on a
        shared machine drifts within seconds.
        """
        out = Alternation(slice_s=slice_s, rounds=rounds)
        child.pause()
        try:
            for _ in range(rounds):
                out.reference.append(reference(slice_s))
                cpu = child.cpu_seconds()
                child.resume()
                start = time.monotonic()
                time.sleep(slice_s)
                end = time.monotonic()
                child.pause()
                out.windows.append((start, end))
                out.system_cpu_s.append(child.cpu_seconds() - cpu)
            out.reference.append(reference(slice_s))
        finally:
            child.resume()
        child.check_alive()
        return out

    # -- filling the replay ------------------------------------------------------------------
    def alternate_warmed(self, child: Child, arrivals: Arrivals, warmed: Callable[[Any], bool],
                         count: int, *, rounds: int, slice_s: float,
                         reference: Callable[[float], tuple[float, float, float]]
                         ) -> Alternation:
        """`alternate` once `count` of `arrivals` satisfy `warmed` (the child has warmed up);
        the child is stopped however that ends."""
        try:
            arrivals.wait_count(warmed, count, timeout_s=READY_TIMEOUT_S, alive=child)
            return self.alternate(child, rounds=rounds, slice_s=slice_s, reference=reference)
        finally:
            self.stop(child)

    def top_up(self, replay: Child, episodes: int) -> None:
        """Insert synthetic episodes until the replay holds at least `episodes`."""
        held = int(self.wait_status(lambda s: True, what="any size", replay=replay)
                   .size_episodes)
        if held >= episodes:
            return
        with self.fleet.running(1) as (actor,):
            before = len(actor.acks)
            while len(actor.acks) - before < episodes - held and actor.error is None:
                replay.check_alive()
                time.sleep(0.05)

    def fill(self, replay: Child) -> int:
        """Insert synthetic episodes until the ring is full; returns episodes in the store."""
        capacity = self.configs["her"][0].capacity_episodes
        n = len(self.fleet.actors)
        start, last_report = time.monotonic(), time.monotonic()
        with self.fleet.running(n) as actors:
            while self.fleet.newest_episode_id() + 1 < capacity:
                replay.check_alive()
                if any(a.error is not None for a in actors):
                    break  # raised when the block exits
                if time.monotonic() - last_report > 15:
                    last_report = time.monotonic()
                    say(f"filling: {self.fleet.newest_episode_id() + 1:,}/{capacity:,} "
                        "episodes inserted")
                time.sleep(0.1)
        status = self.wait_status(lambda s: s.size_episodes >= capacity,
                                  what=f"size {capacity}", replay=replay)
        wall = time.monotonic() - start
        say(f"filled: {status.size_transitions:,} transitions ({wall:.0f} s)")
        self.details["fill"] = {"episodes": int(status.size_episodes),
                                "transitions": int(status.size_transitions),
                                "inserted_total": int(status.inserts), "actors": n,
                                "wall_s": round(wall, 1)}
        return int(status.size_episodes)
