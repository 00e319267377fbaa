"""What /proc says while a run trains: each core's busy share over time, and each process of the
run's CPU seconds (user + system), read every `every` seconds from a thread."""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def core_ticks() -> dict[str, tuple[int, int]]:
    """cpuN → (busy ticks, all ticks) since boot, from /proc/stat (iowait counts as idle)."""
    out: dict[str, tuple[int, int]] = {}
    for line in Path("/proc/stat").read_text().splitlines():
        name, *fields = line.split()
        if not (name.startswith("cpu") and name[3:].isdigit()):
            continue
        ticks = [int(v) for v in fields[:8]]
        idle = ticks[3] + ticks[4]
        out[name] = (sum(ticks) - idle, sum(ticks))
    return out


def descendants(root: int) -> dict[int, str]:
    """pid → command line of every process below `root` (its children, theirs, …)."""
    parents: dict[int, int] = {}
    commands: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            argv = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        # the command name in field 2 may hold spaces: the fields after it follow its ')'
        parents[int(entry.name)] = int(stat.rpartition(")")[2].split()[1])
        commands[int(entry.name)] = argv.replace(b"\0", b" ").decode(errors="replace").strip()
    found: dict[int, str] = {}
    frontier = [root]
    while frontier:
        parent = frontier.pop()
        for pid, ppid in parents.items():
            if ppid == parent and pid not in found:
                found[pid] = commands[pid]
                frontier.append(pid)
    return found


def cpu_seconds(pid: int) -> float | None:
    """The process's user + system CPU seconds; None once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) * TICK_S


@dataclass
class ProcSampler:
    """Samples /proc every `every` seconds until stopped; `root` is the profiler's pid."""

    root: int
    every: float = 0.5
    started: float = field(default_factory=time.monotonic)
    cores: list[tuple[float, dict[str, float]]] = field(default_factory=list)
    """(seconds since start, cpuN → busy share over the interval before it)."""
    process_cpu: dict[int, float] = field(default_factory=dict)
    """pid → the last CPU seconds read (a process's total once it has exited)."""
    commands: dict[int, str] = field(default_factory=dict)
    """pid → its last non-empty command line (a fork not yet exec'd shows its
    parent's: such a reading is replaced)."""
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="proc-sampler", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def _run(self) -> None:
        before = core_ticks()
        while not self._stop.wait(self.every):
            self.sample_processes()
            now = core_ticks()
            shares = {name: (busy - before[name][0]) / max(total - before[name][1], 1)
                      for name, (busy, total) in now.items() if name in before}
            self.cores.append((time.monotonic() - self.started, shares))
            before = now

    def sample_processes(self) -> None:
        for pid, command in descendants(self.root).items():
            seconds = cpu_seconds(pid)
            if seconds is not None:
                self.process_cpu[pid] = seconds
            if command:  # empty while the process execs or once it is a zombie
                self.commands[pid] = command
