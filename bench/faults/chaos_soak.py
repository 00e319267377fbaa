"""One chaos soak run (bench/faults/chaos.py): `hercs up` launched (or resumed) with its
remote actors, the schedule's kills and cuts injected on the run's clock, cuts healed, killed
actors restarted, and the soak's state saved after every injection so that a stopped soak
continues where its clock stopped."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import sys
import time
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench.faults.chaos_actors import Incarnation, RemoteActors
from bench.faults.chaos_plan import Event
from bench.faults.chaos_state import Shape, SoakState
from bench.faults.netns import Host
from bench.faults.remote_actor import ACTOR_EXIT_S
from bench.faults.service_kills import EPOCH, Up
from hercs.apps.launch.router import free_port
from hercs.run.rundir import RunDir

NEVER = re.compile(r"(?!)")
TICK_S = 1.0
"""The loop's longest wait: heals, restarts and kills are this punctual."""
MAX_RESTARTS = 1000
"""`launch.max_restarts` of a soak's run. The default (5 deaths of one child without 5 min of
uptime in between) would end a soak that happens to draw one service 6 times in a row; the
give-up rule is tested elsewhere (tests/integration/test_launcher.py), not here."""


def _cmdline(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
    except OSError:
        return []


class Soak:
    """One run under a schedule (an empty one for a fault-free seed): launch, inject, heal,
    supervise the remote actors, until `hercs up` ends."""

    def __init__(self, state: SoakState, *, links: list[Host], certs: Path, work: Path,
                 shape: Shape) -> None:
        self.state, self.shape, self.links, self.certs = state, shape, links, certs
        self.run_root = work / "runs"
        self.run_dir = self.run_root / state.name
        self.run_root.mkdir(parents=True, exist_ok=True)
        self.state_path = work / f"{state.name}.state.json"
        self.port = free_port("0.0.0.0")  # every address: the router listens on each link
        self.offset, self.started = state.elapsed_s, time.monotonic()
        self.events = [Event(**e) for e in state.events]
        self.history = [Incarnation(**a) for a in state.actors]
        self.actors = RemoteActors(links, endpoint=f"tls/HOST:{self.port}", run=state.name,
                                   certs=certs, out=self.run_root, history=self.history)
        self.cuts: dict[str, tuple[float, dict[str, Any]]] = {}
        """Cut hosts by actor id: (heal due on the run's clock, the injection's record)."""
        self.hosts = dict(zip(self.actors.idents, links, strict=True))
        self.up: Up | None = None

    def now(self) -> float:
        return self.offset + time.monotonic() - self.started

    def _clocked(self, up: Up) -> list[tuple[float, str]]:
        return [(round(self.offset + at - self.started, 2), line) for at, line in up.seen]

    def save(self) -> None:
        self.state.elapsed_s = round(self.now(), 2)
        self.state.actors = [asdict(i) for i in self.history]
        self.state.notes = [*dict.fromkeys(self.state.notes + self.actors.notes)]
        live = self._clocked(self.up) if self.up is not None else []
        saved, self.state.progress = self.state.progress, self.state.progress + live
        self.state.save(self.state_path)
        self.state.progress = saved

    # ------------------------------------------------------------------ hercs up
    def launch(self, *, resume: bool) -> Up:
        common = ["--actors", "0", "--tls-dir", str(self.certs),
                  *[a for h in self.links for a in ("--listen", f"tls/{h.host_ip}:{self.port}")],
                  "--set", f"training.epochs={self.shape.epochs}",
                  "--set", f"launch.max_restarts={MAX_RESTARTS}"]
        argv = [sys.executable, "-m", "hercs.apps.cli", "up"]
        if resume:
            argv += ["--resume", str(self.run_dir), *common]
        else:
            s = self.shape
            argv += ["--task", s.task, "--method", s.method, "--seed", str(s.seed), "--run",
                     self.state.name, "--run-dir", str(self.run_root), *common,
                     *[a for item in s.sets for a in ("--set", item)]]
        self.state.launches.append(f"{self.now():.0f} s: {' '.join(argv[1:])}")
        return Up(argv, self.run_root / f"{self.state.name}.out")

    def _child(self, ident: str) -> int | None:
        """The pid of `hercs up`'s child `ident` if it is running now: the latest pid the
        launcher printed for it, still a process whose command line names this run's
        config and that id (so a pid the kernel has reused is never signalled)."""
        assert self.up is not None
        pid = self.up.pids.get(ident)
        if pid is None:
            return None
        argv = _cmdline(pid)
        ours = str(RunDir(self.run_dir).config) in argv and ident in argv
        return pid if ours else None

    def _stop_up(self, sig: int) -> None:
        """Signal the launcher and wait until it and its children are gone (they die with
        it: PR_SET_PDEATHSIG, hercs/apps/launch/child_process.py)."""
        assert self.up is not None
        children = [pid for ident in self.up.pids if (pid := self._child(ident)) is not None]
        with contextlib.suppress(ProcessLookupError):
            self.up.proc.send_signal(sig)
        status = self.up.finish(120.0)
        self.state.up_exits.append(status)
        deadline = time.monotonic() + 30.0
        while any(self._child_alive(pid) for pid in children) and time.monotonic() < deadline:
            time.sleep(0.1)  # the kernel's SIGKILL to the children: nothing to await
        self.state.progress += self._clocked(self.up)
        self.up = None

    def _due(self, event: Event, now: float) -> bool:
        """On the clock, or (an epoch-gated plan) once its epoch is recorded."""
        if event.after_epoch:
            return self._epochs_recorded() >= event.after_epoch
        return event.at_s <= now

    def _epochs_recorded(self) -> int:
        """The last epoch `hercs up` has printed, over every launch of this soak."""
        live = [] if self.up is None else self.up.seen
        return max((int(m["epoch"]) for _, line in (*self.state.progress, *live)
                    if (m := EPOCH.match(line))), default=0)

    def _child_alive(self, pid: int) -> bool:
        return str(RunDir(self.run_dir).config) in _cmdline(pid)

    # ----------------------------------------------------------------- injections
    def inject(self, event: Event) -> None:
        now = self.now()
        record: dict[str, Any] = {
            "planned_at_s": event.at_s, "at_s": round(now, 2), "kind": event.kind,
            "target": event.target, "duration_s": event.duration_s,
            "wall_s": round(time.time(), 3),
            "wall": datetime.now(UTC).isoformat(timespec="seconds"), "pid": None,
            "outcome": "done"}
        if event.kind == "cut":
            self.hosts[event.target].cut(both_ways=True)
            self.cuts[event.target] = (now + event.duration_s, record)
        elif event.target == "launcher":
            assert self.up is not None
            record["pid"] = self.up.proc.pid
            self._stop_up(signal.SIGKILL)
            self.up = self.launch(resume=True)
        elif event.target in self.actors.hosts:
            record["pid"] = self.actors.kill(event.target, now)
        else:
            pid = self._child(event.target)
            if pid is not None:
                os.kill(pid, signal.SIGKILL)
            record["pid"] = pid
        if record["pid"] is None and event.kind == "kill":
            record["outcome"] = "skipped: not running (between a death and its restart)"
        self.state.injections.append(record)
        shown = "" if record["pid"] is None else f" (pid {record['pid']})"
        outcome = "" if record["outcome"] == "done" else f" — {record['outcome']}"
        print(f"chaos: {now:7.1f} s  {event.describe()}{shown}{outcome}", flush=True)

    def heal(self, ident: str) -> None:
        _, record = self.cuts.pop(ident)
        self.hosts[ident].heal(both_ways=True)
        record["healed_at_s"] = round(self.now(), 2)
        record["healed_wall_s"] = round(time.time(), 3)
        print(f"chaos: {record['healed_at_s']:7.1f} s  healed {ident}'s link", flush=True)

    def _note_restarts(self, restarted: list[tuple[str, float]]) -> None:
        for ident, at in restarted:
            for record in reversed(self.state.injections):
                if record["target"] == ident and record["kind"] == "kill":
                    record.setdefault("restarted_at_s", round(at, 2))
                    break

    # ----------------------------------------------------------------------- run
    def run(self) -> None:
        """Launch (or resume) and inject until `hercs up` ends; the state is saved after each
        injection and on the way out, finished or not."""
        resume = RunDir(self.run_dir).config.is_file()
        if resume and not (self.state.injections
                           and self.state.injections[-1]["kind"] == "interrupted"):
            self.state.injections.append({  # the bench died without its `finally` (SIGKILL)
                "at_s": round(self.now(), 2), "kind": "interrupted", "target": "bench",
                "wall": datetime.now(UTC).isoformat(timespec="seconds"),
                "outcome": "the soak stopped without saving its end (its last save is here)"})
        for incarnation in self.history:
            if incarnation.exit is None and not incarnation.killed_by:  # died with that bench
                incarnation.killed_by = "bench stopped"
        for record in self.state.injections:
            if record["kind"] == "cut" and "healed_at_s" not in record:
                record["outcome"] = "done; ended with the bench (its namespace went with it)"
        if resume:
            self.state.injections.append({
                "at_s": round(self.now(), 2), "kind": "resume", "target": "bench",
                "wall": datetime.now(UTC).isoformat(timespec="seconds"),
                "outcome": "the soak was stopped; continued with hercs up --resume"})
        self.state.loads.append(os.getloadavg()[0])
        last_line, last_count, last_save = self.now(), 0, self.now()
        try:
            self.up = self.launch(resume=resume)
            self.actors.start_all(self.now())
            while True:
                now = self.now()
                for ident in [i for i, (due, _) in self.cuts.items() if due <= now]:
                    self.heal(ident)
                self._note_restarts(self.actors.tend(now))
                while (self.state.next_event < len(self.events)
                       and self._due(self.events[self.state.next_event], now)):
                    self.inject(self.events[self.state.next_event])
                    self.state.next_event += 1
                    self.save()
                if len(self.up.seen) != last_count:
                    last_line, last_count = now, len(self.up.seen)
                elif now - last_line > self.shape.stall_s:
                    self.state.notes.append(f"no line from hercs up for {self.shape.stall_s:g}"
                                            f" s at {now:.0f} s; the run was given up")
                    self._stop_up(signal.SIGTERM)
                    break
                if now - last_save > 30.0:
                    self.save()
                    last_save = now
                try:
                    self.up.wait_for(NEVER, TICK_S)
                except TimeoutError:
                    continue
                except RuntimeError:  # its output ended: the run is over
                    self.state.progress += self._clocked(self.up)
                    self.state.up_exits.append(self.up.finish(120.0))
                    self.up = None
                    break
            for ident in list(self.cuts):  # an actor behind a cut could not hear the end
                self.heal(ident)
            self.actors.stop_all(ACTOR_EXIT_S)
            self.state.finished = True
        finally:
            if not self.state.finished:
                self.state.injections.append({
                    "at_s": round(self.now(), 2), "kind": "interrupted", "target": "bench",
                    "wall": datetime.now(UTC).isoformat(timespec="seconds"),
                    "outcome": f"the soak stopped: {sys.exc_info()[1]!r}"})
                for ident in list(self.cuts):
                    self.heal(ident)
                self.actors.kill_all(self.now())
                if self.up is not None:
                    self._stop_up(signal.SIGTERM)
            self.state.loads.append(os.getloadavg()[0])
            self.save()
