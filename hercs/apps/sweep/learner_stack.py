"""`hercs sweep --stacked`: the learner process of a wave of runs (`hercs learner-stack`), and
how the sweep starts, watches and stops it.

The sweep starts `--jobs` runs at once, each a `hercs up` with `launch.learner_elsewhere`, and
once each run's router is up, one `hercs learner-stack` over them. A stack that dies while runs
of its wave go on is started again over those runs (each resumes from its checkpoint), up to
`MAX_STACK_RESTARTS` times; once every run of the wave has ended it is stopped, and the next
wave starts.
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from hercs.run.rundir import ROUTER

LEARNER_ELSEWHERE = "launch.learner_elsewhere=true"
"""The `--set` of every run of a stacked sweep: its `hercs up` starts no learner."""

MAX_STACK_RESTARTS = 5
ROUTER_WAIT_S = 300.0
"""How long the sweep waits for a wave's routers (a `hercs up` that fails before exits)."""
STOP_WAIT_S = 60.0


def routers_ready(run_dirs: list[Path], since: float) -> bool:
    """Every run's router.json written since `since` (wall clock): its router listens on the
    ports its config.yaml names (a resumed run's old router.json does not count)."""
    for run_dir in run_dirs:
        record = run_dir / ROUTER
        try:
            if record.stat().st_mtime < since:
                return False
        except FileNotFoundError:
            return False
    return True


class WaveLearner:
    """The `hercs learner-stack` process of the runs now running."""

    def __init__(self, log_dir: Path, env: dict[str, str]) -> None:
        self.log_dir, self.env = log_dir, env
        self.proc: subprocess.Popen[bytes] | None = None
        self.restarts = 0
        self.wave = 0

    def start(self, run_dirs: list[Path]) -> None:
        log = self.log_dir / f"learner-stack-{self.wave}.log"
        with log.open("ab") as out:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "hercs.apps.cli", "learner-stack",
                 *(str(d) for d in run_dirs)], stdout=out, stderr=subprocess.STDOUT,
                env=self.env, start_new_session=True)
        print(f"[stack] learner-stack of {len(run_dirs)} runs (pid {self.proc.pid}), log {log}",
              flush=True)

    def start_when_ready(self, run_dirs: list[Path], since: float,
                         any_alive: Callable[[], bool]) -> bool:
        """Start it once the runs' routers are up; False if every run ended first or they
        did not come up in ROUTER_WAIT_S (each run's own log says why)."""
        deadline = time.monotonic() + ROUTER_WAIT_S
        while not routers_ready(run_dirs, since):
            if not any_alive() or time.monotonic() > deadline:
                print(f"[stack] no learner-stack for this wave: its runs' routers were not all "
                      f"up within {ROUTER_WAIT_S:g} s or the runs ended first (each run's log "
                      "says why); its runs end without a learner", flush=True)
                return False
            time.sleep(0.5)
        self.wave += 1
        self.restarts = 0
        self.start(run_dirs)
        return True

    def watch(self, still_running: list[Path]) -> None:
        """Between the sweep's polls: a stack that exited while runs go on is started again
        over them (up to MAX_STACK_RESTARTS); with no run left it is stopped."""
        proc = self.proc
        if proc is None:
            return
        if not still_running:
            self.stop()
            return
        code = proc.poll()
        if code is None:
            return
        if self.restarts >= MAX_STACK_RESTARTS:
            print(f"[stack] learner-stack exited {code}; restarted {self.restarts} times "
                  "already, so its runs stall and end", flush=True)
            self.proc = None
            return
        self.restarts += 1
        print(f"[stack] learner-stack exited {code} while {len(still_running)} runs go on: "
              f"started again ({self.restarts} of at most {MAX_STACK_RESTARTS}); each resumes "
              "from its checkpoint", flush=True)
        self.start(still_running)

    def stop(self) -> None:
        proc, self.proc = self.proc, None
        if proc is None or proc.poll() is not None:
            return
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(STOP_WAIT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(STOP_WAIT_S)
