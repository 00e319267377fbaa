"""`hercs up`: one whole run on one machine (docs/DESIGN.md §1, §6).

What `run_up` does, in order:

1. (hercs/apps/run_plan.py) Names the run if `run.name` is empty
   (`<task>-<method>-s<seed>-<YYYYmmdd-HHMMSS>`) and points the children's
   `transport.connect` at the embedded router (every `listen` endpoint, with a wildcard host
   0.0.0.0 / [::] replaced by loopback). Takes the run directory's lock
   (hercs/apps/run_lock.py, held for the launcher's life): a folder another `hercs up` runs
   is refused at once, naming it (exit 2). Refuses a run directory that already holds files
   (exit 2): a replay would load the old episode log into the new run. With `resume`
   (`hercs up --resume runs/RUN`) it is the other way round: the folder must hold a run that
   can continue without losing results (hercs/apps/resume_check.py: else exit 2, saying why
   and what would work; a finished run exits 0 with nothing started), and every service
   continues it. `restart` (`--resume RUN --restart`) moves what the run made into
   `previous/<time>/` first and starts it over.
2. Opens the router, embedded in this process (a router-mode `Transport` on
   `transport.listen`); port 0 (the default, `tcp/127.0.0.1:0`) means any free port, so two
   runs on one host never collide; an explicit port that is taken fails at once with a clear
   message (exit 1), before anything is written.
3. Writes `runs/<run>/config.yaml` (the full resolved config, which every child reads with
   `--config`; `listen` as asked, `connect` the router's concrete endpoints),
   `runs/<run>/logs/` and `runs/<run>/router.json` (`hercs.run.rundir.RouterRecord`: where the
   router listens, for `hercs actor`/`hercs live --run-dir`; removed when the run stops).
   From here on the embedded router's own Zenoh log lines go to `logs/router.log`
   (`native_output_to`), not among the progress lines.
4. Starts the services as child processes, `python -m hercs.apps.cli <role> --config … --id …`,
   each child's stdout and stderr to `logs/<id>.log`: the replay first (ids `replay-0`), and
   once its liveliness token is up the clusterer, learner, evaluator (`<role>-0`) and
   `actor.num_actors` actors (`actor-0` … `actor-<N-1>`). Children connect as Zenoh clients.
   With `view.live` (`--rerun`, `--rerun-save`) the live view `live-0` (hercs/apps/live_view.py)
   starts right after the replay, and the others once its token is up (so that it sees the
   first episode) or after `LIVE_READY_TIMEOUT_S` without it.
5. Prints one progress line per epoch (`Progress`, hercs/apps/progress.py), and logs remote
   processes (e.g. actors started with `hercs actor --connect … --run …`) joining and leaving.
6. Ends when:
   - the learner exits 0 (its last epoch is done): waits up to a few seconds for the last
     epoch's progress line, stops the others, prints the run directory, returns 0;
   - any other child exits, or the learner exits non-zero: prints the role, id, exit code and
     the last lines of its log and starts it again after a back-off (1 s doubling to 30 s),
     counted in the progress line (`restarts N`). Every service continues where the run
     stands (the replay reloads its log, the learner its checkpoint, the clusterer asks the
     replay, an actor comes back under a new incarnation). A child that dies more often than
     `launch.max_restarts` (without `HEALTHY_S` of uptime in between) ends the run: the others
     are stopped and the status is 1;
   - except an optional child (`OPTIONAL_ROLES`: the live view): its exit is reported the same
     way as a warning, it is not restarted, and training goes on without it (a live view can
     be started again by hand: `hercs live --connect … --run …`);
   - SIGINT (Ctrl-C) / SIGTERM / SIGHUP: stops everything, returns 128 + signal number.

Stopping goes stage by stage — actors, then evaluator/learner/clusterer/live, then the replay last
(so that every episode in flight can still be acked and logged) — with SIGTERM to each child's
process group, a bounded wait (`stop_timeout_s`), then SIGKILL. A second Ctrl-C skips the
waits and kills at once.

No orphans (hercs/apps/child_process.py, which the benchmarks use too): every child runs in its
own process group (Ctrl-C at the terminal reaches only the launcher, which then stops the
children in order) with `PR_SET_PDEATHSIG` = SIGKILL set
between fork and exec, so if the launcher itself is SIGKILLed (or crashes) the kernel kills
every child. The parent-death signal fires when the *thread* that forked the child exits,
so children are only ever started from the main thread (`run_up` checks it). SIGKILL is safe
for the data: the replay acks an episode only after it is in the log.

Progress comes from `Metrics` on `metrics/**` published by the learner (`service` =
`learner/<id>`) at each epoch end. Keys read from its `values` (all optional but `epoch`):
`epoch` (epochs completed, 1-based), `epochs` (total; default `training.epochs`),
`success_rate`, `env_steps_per_s`, `updates_per_s`, `replay_size`, `policy_lag`. A missing
`success_rate` is taken from the `EvalResult` whose `epoch` equals the line's epoch (the line
waits for it until the next epoch's metrics arrive); a missing `replay_size` from the latest
`ReplayStatus.size_episodes`.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from hercs.apps.child_process import describe_exit, log_tail, signal_group, start_child
from hercs.apps.progress import Progress
from hercs.apps.resume_check import CannotResume, plan_resume, set_aside_for_restart
from hercs.apps.router import RouterListenError, open_router_anywhere
from hercs.apps.run_lock import RunBusy, RunLock
from hercs.apps.run_plan import (
    ChildSpec,
    CommandFactory,
    plan_children,
    resolve_run,
    service_command,
)
from hercs.config import HercsConfig, save_yaml
from hercs.errors import ConfigError, InvalidMessage
from hercs.net.backoff import nth_delay
from hercs.net.service_shell import EXIT_CONFIG
from hercs.net.signals import StopSignals
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.run.rundir import (
    RouterRecord,
    RunDir,
    holds_a_run,
    remove_router,
    write_router,
)
from hercs.wire.validation import parse_message

REQUEUE_LOCK_WAIT_S = 180.0
"""A requeued Slurm attempt (SLURM_RESTART_COUNT > 0) waits this long for the run's lock: on
a shared file system the lock of an attempt whose node died (NODE_FAIL) lasts until that
client's lease ends (about 90 s on NFSv4)."""

STOP_STAGES = (("actor",), ("evaluator", "learner", "clusterer", "live"), ("replay",))
"""Roles stopped together, stage after stage; the replay last."""
OPTIONAL_ROLES = frozenset({"live"})
"""Roles whose exit does not end the run: watching training must never stop it."""
MAX_BACKOFF_S = 30.0
"""Restart delays double from `launch.restart_backoff_s` up to this."""
HEALTHY_S = 300.0
"""A child that ran this long before dying has its restart count reset (it was not
crash-looping)."""

STOP_TIMEOUT_S = 10.0
READY_TIMEOUT_S = 120.0
LIVE_READY_TIMEOUT_S = 30.0
FINAL_PROGRESS_TIMEOUT_S = 5.0
LOG_TAIL_LINES = 20
_POLL_S = 1.0


@dataclass
class _Child:
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
class _Launcher:
    config: HercsConfig
    run_dir: Path
    signals: StopSignals
    command: CommandFactory
    stop_timeout_s: float
    ready_timeout_s: float
    out: IO[str]
    err: IO[str]
    children: list[_Child] = field(default_factory=list)
    alive: set[str] = field(default_factory=set)
    restarts_total: int = 0
    scheduled: list[tuple[float, ChildSpec, int]] = field(default_factory=list)
    """Restarts waiting for their back-off: (when, spec, restarts so far)."""

    def __post_init__(self) -> None:
        self.keys = RunKeys(self.config.run.name)
        self.progress = Progress(self.config.training.epochs)
        self._print_lock = threading.RLock()
        self._ours = {self.keys.alive(s.role, s.ident) for s in plan_children(self.config)}

    # ------------------------------------------------------------------ output

    def say(self, line: str, *, error: bool = False) -> None:
        # A terminal gone (SIGHUP) must not break the shutdown that follows.
        with self._print_lock, contextlib.suppress(OSError, ValueError):
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

    def on_metrics(self, key: str, raw: bytes) -> None:
        msg = self._decode(raw, pb.Metrics, "Metrics")
        if isinstance(msg, pb.Metrics):
            with self._print_lock:  # compute and print as one step, so lines stay in order
                lines = self.progress.on_metrics(msg.service, dict(msg.values))
                self._say_all(lines)
            if lines:
                self.signals.wake()

    def on_eval(self, key: str, raw: bytes) -> None:
        msg = self._decode(raw, pb.EvalResult, "EvalResult")
        if isinstance(msg, pb.EvalResult):
            with self._print_lock:
                lines = self.progress.on_eval(int(msg.epoch), msg.success_rate)
                self._say_all(lines)
            if lines:
                self.signals.wake()

    def on_status(self, key: str, raw: bytes) -> None:
        msg = self._decode(raw, pb.ReplayStatus, "ReplayStatus")
        if isinstance(msg, pb.ReplayStatus):
            with self._print_lock:
                self.progress.on_replay_size(msg.size_episodes)

    def on_inserted(self, key: str, raw: bytes) -> None:
        msg = self._decode(raw, pb.EpisodeHeader, "EpisodeHeader")
        if isinstance(msg, pb.EpisodeHeader):
            with self._print_lock:
                self.progress.on_inserted(msg.actor_id)

    def on_alive(self, key: str, alive: bool) -> None:
        (self.alive.add if alive else self.alive.discard)(key)
        actor_prefix = self.keys.prefix + "/alive/actor/"
        self.progress.actors = sum(1 for k in list(self.alive) if k.startswith(actor_prefix))
        if key not in self._ours:
            role_ident = key.removeprefix(self.keys.prefix + "/alive/").replace("/", " ", 1)
            self.say(f"hercs up: remote {role_ident} {'joined' if alive else 'left'}")
        self.signals.wake()

    # ------------------------------------------------------------------ processes

    def start(self, spec: ChildSpec, *, restarts: int = 0) -> _Child:
        config_path = RunDir(self.run_dir).config
        log_path = RunDir(self.run_dir).logs / spec.log_name
        proc = start_child(self.command(spec, config_path), log_path=log_path)
        child = _Child(spec, proc, log_path, restarts=restarts)
        self.children = [c for c in self.children if c.spec != spec or c.proc.poll() is None]
        self.children.append(child)
        again = f" again (restart {restarts})" if restarts else ""
        self.say(f"hercs up: started {spec}{again} (pid {proc.pid}), log {log_path}")
        return child

    def _report_exit(self, child: _Child, code: int, *, then: str = "") -> None:
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
        the learner is done; 1 if a child died more often than `launch.max_restarts`."""
        self._reap_optional()
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
                line = self.progress.interim()
                if line is not None:
                    self.say(line)
            self.signals.wait(_POLL_S)

    def stop_all(self) -> None:
        """Stop every child, stage by stage; returns only when all have exited. A stop signal
        received meanwhile skips the remaining graceful waits."""
        signals_before = len(self.signals.received)
        for roles in STOP_STAGES:
            stage = [c for c in self.children if c.spec.role in roles]
            live = [c for c in stage if c.proc.poll() is None]
            for child in live:
                child.expected_exit = True
                child.signal(signal.SIGTERM)
            deadline = time.monotonic() + self.stop_timeout_s
            for child in live:
                while child.proc.poll() is None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or len(self.signals.received) > signals_before:
                        break
                    with contextlib.suppress(subprocess.TimeoutExpired):
                        child.proc.wait(min(remaining, 0.5))
            for child in live:
                if child.proc.poll() is None:
                    self.say(f"hercs up: {child.spec} did not stop within "
                             f"{self.stop_timeout_s:g} s; killing it", error=True)
                    child.signal(signal.SIGKILL)
                    child.proc.wait()
            for child in stage:  # anything the child forked into its group
                child.signal(signal.SIGKILL)


def run_up(
    config: HercsConfig,
    *,
    command: CommandFactory = service_command,
    stop_timeout_s: float = STOP_TIMEOUT_S,
    ready_timeout_s: float = READY_TIMEOUT_S,
    out: IO[str] | None = None,
    err: IO[str] | None = None,
    resume: bool = False,
    restart: bool = False,
) -> int:
    """Run a whole experiment locally (see the module docstring); returns the exit status:
    0 done (or, with `resume`, finished already), 1 a service failed or the router could not
    listen, 2 the run directory is taken, is in use by another `hercs up`, or (with
    `resume`) holds no run or one that cannot continue without losing results (`restart`:
    start it over, its old files set aside), 128 + n after signal n. Must be called on the
    main thread."""
    out = out or sys.stdout
    err = err or sys.stderr
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("run_up must run on the main thread (signal handlers, and "
                           "PR_SET_PDEATHSIG fires when the forking thread exits)")
    config = resolve_run(config)
    run_dir = Path(config.run.run_dir) / config.run.name
    if resume and not RunDir(run_dir).config.is_file():
        print(f"hercs up: --resume {run_dir}: no run there (no config.yaml)", file=err,
              flush=True)
        return 2
    made = [p for p in (run_dir, *run_dir.parents) if not p.exists()]
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        lock = RunLock.take(run_dir, wait_s=REQUEUE_LOCK_WAIT_S if resume and int(
            os.environ.get("SLURM_RESTART_COUNT", "0") or 0) > 0 else 0.0)
    except (RunBusy, OSError) as exc:
        print(f"hercs up: {exc}", file=err, flush=True)
        return 2
    try:
        if not resume and holds_a_run(run_dir):
            print(f"hercs up: {run_dir} already exists and is not empty; pick another --run "
                  "(or leave it empty for a fresh name), or move that directory away",
                  file=err, flush=True)
            return 2
        if resume and restart:
            aside = set_aside_for_restart(run_dir)
            print(f"hercs up: --restart: run {config.run.name} starts over from epoch 1"
                  + (f"; what it held is kept in {aside}" if aside else ""), file=out,
                  flush=True)
        elif resume:
            plan = plan_resume(run_dir, epochs=config.training.epochs)
            if plan.finished:
                print(f"hercs up: {plan.describe(config.run.name)}", file=out, flush=True)
                return 0
        return _run(config, run_dir, command=command, stop_timeout_s=stop_timeout_s,
                    ready_timeout_s=ready_timeout_s, out=out, err=err, resume=resume)
    except CannotResume as exc:
        print(f"hercs up: {exc}", file=err, flush=True)
        return 2
    finally:
        lock.release()
        if made and not holds_a_run(run_dir):  # made here, nothing written (no router)
            with contextlib.suppress(OSError):
                for folder in made:
                    folder.rmdir()


def _run(config: HercsConfig, run_dir: Path, *, command: CommandFactory,
         stop_timeout_s: float, ready_timeout_s: float, out: IO[str], err: IO[str],
         resume: bool) -> int:
    """`run_up` once the run directory is this process's: router, children, progress."""
    signals = StopSignals((signal.SIGINT, signal.SIGTERM, signal.SIGHUP),
                          wake_on=(signal.SIGCHLD,))
    with signals:
        try:
            router, listening = open_router_anywhere(config.transport.listen, config.security)
        except ConfigError as exc:
            print(f"hercs up: {exc}", file=err, flush=True)
            return 2
        except RouterListenError as exc:
            print(f"hercs up: {exc}", file=err, flush=True)
            return 1
        config = resolve_run(config, listening=listening)
        RunDir(run_dir).logs.mkdir(parents=True, exist_ok=True)
        with native_output_to(RunDir(run_dir).router_log, out, err) as (out, err):
            launcher = _Launcher(config=config, run_dir=run_dir, signals=signals,
                                 command=command, stop_timeout_s=stop_timeout_s,
                                 ready_timeout_s=ready_timeout_s, out=out, err=err)
            status = 1
            try:
                save_yaml(config, RunDir(run_dir).config)
                write_router(run_dir, RouterRecord.for_listen(listening))
                launcher.say(f"hercs up: {'resuming ' if resume else ''}run "
                             f"{config.run.name}, directory {run_dir}, router on {listening}")
                router.subscribe(launcher.keys.all_metrics, launcher.on_metrics)
                router.subscribe(launcher.keys.eval_result, launcher.on_eval)
                router.subscribe(launcher.keys.status, launcher.on_status, drop_oldest=True)
                router.subscribe(launcher.keys.inserted, launcher.on_inserted,
                                 drop_oldest=True)
                router.watch_alive(launcher.keys.all_alive, launcher.on_alive)
                status = launcher.run()
            finally:
                launcher.stop_all()
                with launcher._print_lock:
                    launcher._say_all(launcher.progress.flush())
                router.close()
                remove_router(run_dir)
            if status == 0:
                launcher.say(f"hercs up: run {config.run.name} finished; run directory: "
                             f"{run_dir}")
            else:
                launcher.say(f"hercs up: run {config.run.name} stopped; run directory: "
                             f"{run_dir}", error=status == 1)
            return status


@contextlib.contextmanager
def native_output_to(path: Path, out: IO[str], err: IO[str]
                     ) -> Iterator[tuple[IO[str], IO[str]]]:
    """Point file descriptors 1 and 2 at `path` for the block and yield streams on the
    terminal's stdout and stderr for hercs's own lines (also `sys.stdout`/`sys.stderr`
    meanwhile).

    The Zenoh router inside `hercs up` logs through Rust, which writes to descriptor 1
    (`RUST_LOG`'s lines, errors included) or 2, not through Python's streams: its lines
    (e.g. `ERROR … Unknown id` after a query that access control denied) would land among the
    progress lines. With this they go to `logs/router.log`, as every child's output goes to
    its own log, while every line hercs prints still reaches the terminal. A stream that is
    not this process's own stdout/stderr (a test's) is kept as it is."""
    redirected: list[tuple[int, str, IO[str], IO[str]]] = []
    try:
        log_fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        try:
            for stream, fd, name in ((out, 1, "stdout"), (err, 2, "stderr")):
                try:
                    own = stream is getattr(sys, name) and stream.fileno() == fd
                except (AttributeError, OSError, ValueError):  # no descriptor: a test's
                    own = False
                if own:
                    stream.flush()
                    terminal = open(os.dup(fd), "w", buffering=1,  # noqa: SIM115 (below)
                                    encoding=getattr(stream, "encoding", None) or "utf-8",
                                    errors=getattr(stream, "errors", None) or "replace")
                    redirected.append((fd, name, stream, terminal))
                    os.dup2(log_fd, fd)
                    setattr(sys, name, terminal)
        finally:
            os.close(log_fd)
        streams = {name: tty for _, name, _, tty in redirected}
        yield streams.get("stdout", out), streams.get("stderr", err)
    finally:
        for fd, name, stream, tty in reversed(redirected):
            with contextlib.suppress(OSError, ValueError):
                tty.flush()
            os.dup2(tty.fileno(), fd)
            setattr(sys, name, stream)
            with contextlib.suppress(OSError, ValueError):
                tty.close()
