"""The chaos soak's remote actors and their supervisor (bench.faults.chaos).

Plays the supervisor of the actors' hosts: starts each actor in its namespace, and again after
a kill or a death, each start an incarnation with its own log and actor id. Why and how:
docs/FAULTS.md, "The chaos soak".
"""

from __future__ import annotations

import contextlib
import signal
from dataclasses import dataclass
from pathlib import Path

from bench.faults.netns import Host
from bench.faults.remote_actor import Actor, actor_ident, start_actor

RESTART_S = 1.0
"""How long after a kill the host's supervisor starts the actor again (the launcher's own
first back-off, `launch.restart_backoff_s`)."""


@dataclass
class Incarnation:
    """One start of one remote actor, as recorded in the soak's state."""

    ident: str
    number: int
    log: str
    """Its log's file name (in the soak's run folder's parent)."""
    started_at_s: float
    exit: int | None = None
    killed_at_s: float | None = None
    """When it was SIGKILLed on purpose (run clock), else None."""
    killed_by: str = ""
    """Who killed it: "schedule", "bench stopped" (the soak itself was interrupted), or ""
    (it ended by itself: its exit status counts)."""

    @property
    def key(self) -> str:
        return f"{self.ident}#{self.number}"


class RemoteActors:
    """The actors of a soak, one per host, and the supervisor that restarts them."""

    def __init__(self, links: list[Host], *, endpoint: str, run: str, certs: Path, out: Path,
                 history: list[Incarnation]) -> None:
        """`endpoint` is the router's `tls/HOST:PORT` with HOST filled in per link;
        `history` is the soak's list of incarnations (appended to, kept across resumes)."""
        self.hosts = {actor_ident(i + 1): (i + 1, host) for i, host in enumerate(links)}
        self.endpoint = endpoint
        self.run, self.certs, self.out = run, certs, out
        self.history = history
        self.running: dict[str, tuple[Incarnation, Actor]] = {}
        self.restart_at: dict[str, float] = {}
        self.notes: list[str] = []

    @property
    def idents(self) -> list[str]:
        return list(self.hosts)

    def start(self, ident: str, now: float) -> Incarnation:
        index, host = self.hosts[ident]
        number = sum(i.ident == ident for i in self.history)
        incarnation = Incarnation(ident, number, f"{self.run}.{ident}.{number}.log", now)
        actor = start_actor(host, index=index,
                            endpoint=self.endpoint.replace("HOST", host.host_ip), run=self.run,
                            certs=self.certs, out=self.out, log_name=incarnation.log)
        self.history.append(incarnation)
        self.running[ident] = (incarnation, actor)
        self.restart_at.pop(ident, None)
        return incarnation

    def start_all(self, now: float) -> None:
        for ident in self.hosts:
            self.start(ident, now)

    def kill(self, ident: str, now: float) -> int | None:
        """SIGKILL the actor `ident` (it is ours: the bench started it); its restart is due
        `RESTART_S` later. None if it is not running (between a death and its restart)."""
        if ident not in self.running:
            return None
        incarnation, actor = self.running.pop(ident)
        actor.proc.send_signal(signal.SIGKILL)
        incarnation.exit = actor.proc.wait()
        incarnation.killed_at_s, incarnation.killed_by = now, "schedule"
        self.restart_at[ident] = now + RESTART_S
        return actor.proc.pid

    def tend(self, now: float) -> list[tuple[str, float]]:
        """What a host supervisor does each second while the run goes on: start the actors
        whose restart is due, and restart at once one that died with a non-zero status.
        Returns (ident, run clock) of each restart."""
        for ident, (incarnation, actor) in list(self.running.items()):
            code = actor.proc.poll()
            if code is None:
                continue
            incarnation.exit = code
            del self.running[ident]
            if code != 0:
                self.notes.append(f"{incarnation.key} exited with status {code} at "
                                  f"{now:.0f} s, unasked; restarted")
                self.restart_at[ident] = now
            else:
                self.notes.append(f"{incarnation.key} exited 0 at {now:.0f} s, before the "
                                  "run ended; not restarted")
        restarted = []
        for ident, due in list(self.restart_at.items()):
            if due <= now:
                self.start(ident, now)
                restarted.append((ident, now))
        return restarted

    def stop_all(self, timeout_s: float) -> None:
        """Once the run has ended: each actor stops by itself (the learner said the run is
        finished), else it gets SIGTERM after `timeout_s` (noted). Pending restarts lapse."""
        self.restart_at.clear()
        for ident, (incarnation, actor) in list(self.running.items()):
            code, stopped = actor.stop(timeout_s)
            incarnation.exit = code
            if stopped:
                self.notes.append(f"{incarnation.key} did not stop by itself within "
                                  f"{timeout_s:g} s of the run's end; stopped with SIGTERM "
                                  f"(exit {code})")
            del self.running[ident]

    def kill_all(self, now: float) -> None:
        """However the soak ends: no actor of ours outlives it."""
        self.restart_at.clear()
        for incarnation, actor in self.running.values():
            with contextlib.suppress(ProcessLookupError):
                actor.proc.kill()
            incarnation.exit = actor.proc.wait()
            incarnation.killed_at_s, incarnation.killed_by = now, "bench stopped"
        self.running.clear()
