"""The supervisor inside `hercs up`: starts the run's services as child processes, restarts one
that dies (with back-off, never a diverged learner), prints the progress lines, ends a stalled
run and stops everything stage by stage (actors first, the replay last).

It holds no Zenoh session: `hercs.apps.launch.launcher` subscribes its callbacks on the
embedded router and drives `run` and `stop_all` (docs/DESIGN.md §6, "`hercs up`, step by step").
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from hercs.apps.launch.child_process import describe_exit, log_tail, signal_group, start_child
from hercs.apps.launch.live_line import LiveLine, is_terminal
from hercs.apps.launch.progress import Progress
from hercs.apps.launch.run_plan import (
    ChildSpec,
    CommandFactory,
    plan_children,
    remote_actor_command,
)
from hercs.apps.launch.stall import StallWatch, expected_first_epoch_s
from hercs.config import HercsConfig
from hercs.config.limits import MAX_BACKOFF_S
from hercs.errors import InvalidMessage
from hercs.net.backoff import nth_delay
from hercs.net.service_shell import EXIT_CONFIG, EXIT_DIVERGED
from hercs.net.signals import StopSignals
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.roles import SERVICE_ROLES
from hercs.run.rundir import RunDir
from hercs.wire.validation import parse_message

STOP_STAGES = tuple(tuple(r.name for r in SERVICE_ROLES.values() if r.stop_stage == stage)
                    for stage in sorted({r.stop_stage for r in SERVICE_ROLES.values()}))
"""Roles stopped together, stage after stage (hercs/roles.py): the actors first, the replay
last."""
OPTIONAL_ROLES = frozenset(r.name for r in SERVICE_ROLES.values() if r.optional)
"""Roles whose exit does not end the run: watching training must never stop it."""
HEALTHY_S = 300.0
"""A child that ran this long before dying has its restart count reset (it was not
crash-looping)."""

EXIT_STALLED = 5
"""`hercs up`'s status when the run stalled: no epoch ended within its bound (StallWatch)."""

LIVE_READY_TIMEOUT_S = 30.0
FINAL_PROGRESS_TIMEOUT_S = 5.0
LOG_TAIL_LINES = 20
LIVE_REDRAW_S = 0.1
"""The live line is redrawn at most this often as the learner's cycles arrive."""
_POLL_S = 1.0


@dataclass(frozen=True)
class RunProgressEnd:
    """The last `RunProgress` of a learner that `hercs up` did not start."""

    diverged: bool
    epoch: int


@dataclass
class Child:
    spec: ChildSpec
    proc: subprocess.Popen[bytes]
    log_path: Path
    expected_exit: bool = False
    started: float = field(default_factory=time.monotonic)
    restarts: int = 0
    """Restarts of this spec so far (carried over to the new child)."""

    def signal(self, sig: int) -> None:
        """Signal the child's whole process group (it leads it), so helpers it forked go too."""
        signal_group(self.proc, sig)


@dataclass
class Supervisor:
    config: HercsConfig
    run_dir: Path
    signals: StopSignals
    command: CommandFactory
    stop_timeout_s: float
    ready_timeout_s: float
    out: IO[str]
    err: IO[str]
    children: list[Child] = field(default_factory=list)
    alive: set[str] = field(default_factory=set)
    restarts_total: int = 0
    scheduled: list[tuple[float, ChildSpec, int]] = field(default_factory=list)
    """Restarts waiting for their back-off: (when, spec, restarts so far)."""
    first_epoch: int = 1
    """The epoch the run trains first (a resumed run's, after its checkpoint)."""

    def __post_init__(self) -> None:
        self.keys = RunKeys(self.config.run.name)
        self.progress = Progress.for_run(self.config, first_epoch=self.first_epoch)
        self.live = LiveLine(self.out, self.err) if is_terminal(self.out) else None
        """The live line of a terminal (none in a log: its lines stay one per epoch)."""
        self._live_drawn = -LIVE_REDRAW_S
        self.stall = StallWatch(factor=self.config.launch.stall_factor,
                                first_epoch_s=expected_first_epoch_s(self.config))
        self._print_lock = threading.RLock()
        self._ours = {self.keys.alive(s.role, s.ident) for s in plan_children(self.config)}
        self.learner_ended: RunProgressEnd | None = None
        """With `launch.learner_elsewhere`: how the run's learner, a process not ours, said
        the run ended (None while it trains)."""

    # ------------------------------------------------------------------ output

    def say(self, line: str, *, error: bool = False) -> None:
        # A terminal gone (SIGHUP) must not break the shutdown that follows.
        with self._print_lock, contextlib.suppress(OSError, ValueError):
            if self.live is not None:
                self.live.say(line, error=error)
            else:
                print(line, file=self.err if error else self.out, flush=True)

    def _say_all(self, lines: list[str]) -> None:
        for line in lines:
            self.say(line)

    # ------------------------------------------------------------------ zenoh callbacks
    # They run on the transport's threads: bookkeeping and printing only, then wake the loop.

    def _decode(self, raw: bytes, cls: type, what: str) -> object | None:
        try:
            return parse_message(raw, cls, max_bytes=self.config.replay.max_message_bytes)
        except InvalidMessage as exc:
            self.say(f"hercs up: ignoring a bad {what} message: {exc}", error=True)
            return None

    def _print_progress(self, update: Callable[[], list[str]]) -> None:
        """Prints the progress lines `update` returns, waking the loop where there are any."""
        with self._print_lock:  # compute and print as one step, so lines stay in order
            lines = update()
            self._say_all(lines)
        if lines:
            self.signals.wake()

    def on_metrics(self, key: str, raw: bytes) -> None:
        msg = self._decode(raw, pb.Metrics, "Metrics")
        if isinstance(msg, pb.Metrics):
            if msg.service.startswith("learner/") and "epoch" in msg.values:
                with self._print_lock:
                    self.stall.epoch_ended(int(msg.values["epoch"]))
            self._print_progress(lambda: self.progress.on_metrics(msg.service, dict(msg.values)))

    def on_eval(self, key: str, raw: bytes) -> None:
        msg = self._decode(raw, pb.EvalResult, "EvalResult")
        if isinstance(msg, pb.EvalResult):
            self._print_progress(lambda: self.progress.on_eval(int(msg.epoch), msg.success_rate))

    def on_status(self, key: str, raw: bytes) -> None:
        msg = self._decode(raw, pb.ReplayStatus, "ReplayStatus")
        if isinstance(msg, pb.ReplayStatus):
            with self._print_lock:
                self.progress.on_replay_status(msg)

    def on_run_progress(self, key: str, raw: bytes) -> None:
        msg = self._decode(raw, pb.RunProgress, "RunProgress")
        if isinstance(msg, pb.RunProgress):
            with self._print_lock:
                self.progress.on_run_progress(msg)
                # each epoch's first and last cycle always, others at most LIVE_REDRAW_S apart
                status = self.progress.live_status()
                self._draw_live(force=status.cycle in (1, status.cycles_per_epoch))
            if self.config.launch.learner_elsewhere and (msg.finished or msg.diverged):
                self.learner_ended = RunProgressEnd(diverged=msg.diverged, epoch=int(msg.epoch))
                self.signals.wake()

    def _draw_live(self, *, force: bool) -> None:
        """Redraw the live line (a terminal's), unless it was drawn under `LIVE_REDRAW_S` ago
        and not `force`. Under the print lock."""
        now = time.monotonic()
        if self.live is None or (not force and now - self._live_drawn < LIVE_REDRAW_S):
            return
        self._live_drawn = now
        with contextlib.suppress(OSError, ValueError):
            self.live.show(self.progress.live_status())

    def on_inserted(self, key: str, raw: bytes) -> None:
        msg = self._decode(raw, pb.EpisodeHeader, "EpisodeHeader")
        if isinstance(msg, pb.EpisodeHeader):
            with self._print_lock:
                self.progress.on_inserted(msg.actor_id)
                self.stall.episode_stored()

    def on_alive(self, key: str, alive: bool) -> None:
        (self.alive.add if alive else self.alive.discard)(key)
        actor_prefix = self.keys.prefix + "/alive/actor/"
        self.progress.actors = sum(1 for k in list(self.alive) if k.startswith(actor_prefix))
        if key not in self._ours:
            role_ident = key.removeprefix(self.keys.prefix + "/alive/").replace("/", " ", 1)
            self.say(f"hercs up: remote {role_ident} {'joined' if alive else 'left'}")
        self.signals.wake()

    # ------------------------------------------------------------------ processes

    def start(self, spec: ChildSpec, *, restarts: int = 0) -> Child:
        run_dir = RunDir(self.run_dir)
        config_path, log_path = run_dir.config, run_dir.logs / spec.log_name
        proc = start_child(self.command(spec, config_path), log_path=log_path)
        child = Child(spec, proc, log_path, restarts=restarts)
        self.children = [c for c in self.children if c.spec != spec or c.proc.poll() is None]
        self.children.append(child)
        again = f" again (restart {restarts})" if restarts else ""
        self.say(f"hercs up: started {spec}{again} (pid {proc.pid}), log {log_path}")
        return child

    def _report_exit(self, child: Child, code: int, *, then: str = "") -> None:
        goes_on = "; training goes on without it" if child.spec.role in OPTIONAL_ROLES else then
        lines = [f"hercs up: {child.spec.role} {child.spec.ident} exited unexpectedly "
                 f"({describe_exit(code)}){goes_on}; last lines of {child.log_path}:"]
        lines += [f"  | {line}" for line in log_tail(child.log_path, LOG_TAIL_LINES)]
        self.say("\n".join(lines), error=True)

    def _reap_optional(self) -> None:
        """Report optional children that exited, once; they never end the run."""
        for child in self.children:
            if child.spec.role in OPTIONAL_ROLES and not child.expected_exit:
                code = child.proc.poll()
                if code is not None:
                    child.expected_exit = True
                    self._report_exit(child, code)

    def check_children(self) -> int | None:
        """None while all is well (children that died are scheduled for a restart); 0 once
        the learner is done; 1 if a child died more often than `launch.max_restarts` or
        refused its configuration; `EXIT_DIVERGED` if the learner's training diverged."""
        self._reap_optional()
        ended = self.learner_ended
        if ended is not None and ended.diverged:
            self.say(f"hercs up: the run's learner (not started here: launch.learner_elsewhere) "
                     f"says its training diverged after epoch {ended.epoch}; its own log says "
                     "where and what is kept, so the run stops", error=True)
            return EXIT_DIVERGED
        if ended is not None:
            return 0
        exited = [(c, code) for c in self.children
                  if not c.expected_exit and (code := c.proc.poll()) is not None]
        for child, code in exited:
            if child.spec.role == "learner" and code == 0:
                child.expected_exit = True
                return 0
        # An actor exits 0 only when it leaves on purpose: the learner announced the run
        # finished (usually a moment before the learner itself exits). Not a failure.
        for child, code in exited:
            if child.spec.role == "actor" and code == 0:
                child.expected_exit = True
        exited = [(c, code) for c, code in exited if not c.expected_exit]
        failed = False
        for child, code in exited:
            child.expected_exit = True
            restarts = 0 if time.monotonic() - child.started >= HEALTHY_S else child.restarts
            limit = self.config.launch.max_restarts
            if code == EXIT_DIVERGED:
                # A restart would resume from its checkpoint into the same divergence.
                self._report_exit(child, code, then="; its training diverged (its log's last "
                                                    "lines say where and what is kept), which "
                                                    "a restart would repeat, so the run stops")
                return EXIT_DIVERGED
            if code == EXIT_CONFIG:
                # It refused its configuration: a restart reads the same config.yaml.
                self._report_exit(child, code, then="; it refused the run's configuration, "
                                                    "which a restart cannot change, so the "
                                                    "run stops")
                failed = True
                continue
            if restarts >= limit:
                self._report_exit(child, code, then=f"; it was restarted {restarts} times "
                                                    "already, so the run stops")
                failed = True
                continue
            delay = nth_delay(self.config.launch.restart_backoff_s, restarts, MAX_BACKOFF_S)
            self._report_exit(child, code, then=f"; restarting it in {delay:g} s "
                                                f"({restarts + 1} of at most {limit})")
            self.scheduled.append((time.monotonic() + delay, child.spec, restarts + 1))
        return 1 if failed else None

    def restart_due(self) -> None:
        """Start the children whose restart back-off has passed."""
        now = time.monotonic()
        due = [item for item in self.scheduled if item[0] <= now]
        self.scheduled = [item for item in self.scheduled if item[0] > now]
        for _, spec, restarts in due:
            self.start(spec, restarts=restarts)
            self.restarts_total += 1
            self.progress.restarts = self.restarts_total

    def _stall_report(self) -> str:
        """What stalled, since when, and where to look."""
        silent = [f"{c.spec.role} {c.spec.ident}" for c in self.children
                  if c.proc.poll() is None and c.spec.role not in OPTIONAL_ROLES
                  and self.keys.alive(c.spec.role, c.spec.ident) not in self.alive]
        return (f"hercs up: run {self.config.run.name} stalled: {self.stall.describe()}. "
                + (f"Not seen alive on the router (stopped or hung): {', '.join(silent)}. "
                   if silent else "")
                + f"The services' logs are in {RunDir(self.run_dir).logs}; stopping the run "
                  f"(exit {EXIT_STALLED}).")

    def _interrupted(self) -> int:
        sig = self.signals.received[0]
        self.say(f"hercs up: got {signal.Signals(sig).name}, stopping the run "
                 "(Ctrl-C again to kill at once)")
        return 128 + sig

    def wait_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Wait for `done()` while nothing else happens; False on timeout, a stop signal or a
        child exit (which the main loop then reports)."""
        deadline = time.monotonic() + timeout_s
        while not done():
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self.signals.stop_requested:
                return False
            self._reap_optional()
            if any(c.proc.poll() is not None for c in self.children if not c.expected_exit):
                return False
            self.signals.wait(min(remaining, _POLL_S))
        return True

    def run(self) -> int:
        specs = plan_children(self.config)
        replay = specs[0]
        self.start(replay)
        replay_key = self.keys.alive(replay.role, replay.ident)
        if not self.wait_until(lambda: replay_key in self.alive, self.ready_timeout_s):
            if self.signals.stop_requested:
                return self._interrupted()
            status = self.check_children()
            if status is not None:
                return 1
            self.say(f"hercs up: {replay} did not come up within {self.ready_timeout_s:g} s "
                     f"(no liveliness token {replay_key}); see {self.children[0].log_path}",
                     error=True)
            return 1
        rest = specs[1:]
        if rest and rest[0].role == "live":
            live = self.start(rest.pop(0))
            live_key = self.keys.alive(live.spec.role, live.spec.ident)
            if not self.wait_until(lambda: live_key in self.alive or live.expected_exit,
                                   LIVE_READY_TIMEOUT_S):
                if self.signals.stop_requested:
                    return self._interrupted()
                status = self.check_children()
                if status is not None:
                    return status
                if not live.expected_exit:
                    self.say(f"hercs up: {live.spec} is not up after {LIVE_READY_TIMEOUT_S:g} s; "
                             f"starting the run anyway (see {live.log_path})", error=True)
        for spec in rest:
            self.start(spec)
        self.say(f"hercs up: run {self.config.run.name} is running "
                 f"({self.config.training.epochs} epochs); Ctrl-C to stop")
        if self.config.actor.num_actors == 0:
            self.say(waiting_for_actors_line(self.config))
        while True:
            if self.signals.stop_requested:
                return self._interrupted()
            status = self.check_children()
            if status == 0:
                self.wait_until(lambda: self.progress.last_printed >= self.config.training.epochs,
                                FINAL_PROGRESS_TIMEOUT_S)
                return 0
            if status is not None:
                return status
            self.restart_due()
            with self._print_lock:
                # the clock runs while actors can act: remote ones may join much later, and
                # leave (a dead node, whose job Slurm requeues once it sees the node down)
                if self.config.actor.num_actors > 0 or self.progress.actors:
                    self.stall.begin()
                else:
                    self.stall.hold()
                if self.stall.stalled():
                    self.say(self._stall_report(), error=True)
                    return EXIT_STALLED
            with self._print_lock:
                if self.live is not None:  # the live line says what the interim line would
                    self._draw_live(force=True)
                else:
                    line = self.progress.interim()
                    if line is not None:
                        self.say(line)
            self.signals.wait(_POLL_S)

    def stop_all(self) -> None:
        """Stop every child, stage by stage; returns only when all have exited. A stop signal
        received meanwhile skips the remaining graceful waits."""
        with self._print_lock:
            if self.live is not None:
                self.live.close()
                self.live = None  # the stop's lines and the last ones print plainly
        signals_before = len(self.signals.received)
        for roles in STOP_STAGES:
            stage = [c for c in self.children if c.spec.role in roles]
            live = [c for c in stage if c.proc.poll() is None]
            for child in live:
                child.expected_exit = True
                child.signal(signal.SIGTERM)
                child.signal(signal.SIGCONT)  # a stopped child (a stall) handles it only then
            deadline = time.monotonic() + self.stop_timeout_s
            for child in live:
                while child.proc.poll() is None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or len(self.signals.received) > signals_before:
                        break
                    with contextlib.suppress(subprocess.TimeoutExpired):
                        child.proc.wait(min(remaining, 0.5))
            hurried = len(self.signals.received) > signals_before
            for child in live:
                if child.proc.poll() is None:
                    # say why it is killed: a second Ctrl-C cut its wait short, or its time ran out
                    self.say(f"hercs up: stopping {child.spec} at once (a second stop signal)"
                             if hurried else f"hercs up: {child.spec} did not stop within "
                             f"{self.stop_timeout_s:g} s; killing it", error=not hurried)
                    child.signal(signal.SIGKILL)
                    child.proc.wait()
            for child in stage:  # anything the child forked into its group
                child.signal(signal.SIGKILL)


def waiting_for_actors_line(config: HercsConfig) -> str:
    """What a run of remote actors only (`--actors 0`) says at its start: that it waits, and
    the command that starts an actor (where only this host can reach the router, how to let
    others in)."""
    command, reachable = remote_actor_command(config)
    where = ("on any host that reaches this one (HOST: this host's name or address)"
             if "HOST" in command else "on any host that reaches this router") if reachable \
        else ("on this host (the router listens on loopback only; for other hosts start the "
              "run with --listen tls/0.0.0.0:7447, docs/SECURITY.md)")
    return (f"hercs up: waiting for remote actors (--actors 0 starts none here): training "
            f"begins when one joins; start one {where}: {command}")
