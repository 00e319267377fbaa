"""`hercs up`: one whole run on one machine (docs/DESIGN.md §1, §6).

`run_up` takes the run directory, opens the Zenoh router in this process, writes `config.yaml`
and `router.json` and hands the services to the `Supervisor`. Exit status: 0 done, 1 a service
failed or the router could not listen, 2 the run directory cannot be used, 4 diverged, 5
stalled, 128 + n after signal n.
Main thread only (the children's parent-death signal, hercs/apps/launch/child_process.py).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from hercs.apps.launch.resume_check import (
    CannotResume,
    plan_resume,
    set_aside_for_restart,
    settings_not_applied,
)
from hercs.apps.launch.router import RouterListenError, open_router_anywhere
from hercs.apps.launch.run_lock import RunBusy, RunLock
from hercs.apps.launch.run_plan import (
    CommandFactory,
    child_argv,
    resolve_run,
)
from hercs.apps.launch.supervisor import Supervisor
from hercs.apps.tracking.session import check_installed, open_tracking
from hercs.config import HercsConfig, save_yaml
from hercs.errors import ConfigError
from hercs.net.signals import StopSignals
from hercs.run.router_record import RouterRecord, remove_router, write_router
from hercs.run.rundir import (
    RunDir,
    holds_a_run,
)

REQUEUE_LOCK_WAIT_S = 180.0
"""A requeued Slurm attempt (SLURM_RESTART_COUNT > 0) waits this long for the run's lock: on
a shared file system the lock of an attempt whose node died (NODE_FAIL) lasts until that
client's lease ends (about 90 s on NFSv4)."""

STOP_TIMEOUT_S = 10.0
READY_TIMEOUT_S = 120.0


def run_up(
    config: HercsConfig,
    *,
    command: CommandFactory = child_argv,
    stop_timeout_s: float = STOP_TIMEOUT_S,
    ready_timeout_s: float = READY_TIMEOUT_S,
    out: IO[str] | None = None,
    err: IO[str] | None = None,
    resume: bool = False,
    restart: bool = False,
) -> int:
    """Run a whole experiment locally (docs/DESIGN.md §6); returns the exit status:
    0 done (or, with `resume`, finished already), 1 a service failed or the router could not
    listen, 2 the run directory is taken, is in use by another `hercs up`, or (with
    `resume`) holds no run or one that cannot continue without losing results (`restart`:
    start it over, its old files set aside), 4 the learner's training diverged
    (`EXIT_DIVERGED`), 5 the run stalled (`EXIT_STALLED`), 128 + n after signal n. Must be
    called on the main thread."""
    out = out or sys.stdout
    err = err or sys.stderr
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("run_up must run on the main thread (signal handlers, and "
                           "PR_SET_PDEATHSIG fires when the forking thread exits)")
    config = resolve_run(config)
    try:
        check_installed(config.tracking)
    except ConfigError as exc:
        print(f"hercs up: {exc}", file=err, flush=True)
        return 2
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
    first_epoch = 1
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
            plan = plan_resume(run_dir, epochs=config.training.epochs, config=config)
            if plan.finished:
                print(f"hercs up: {plan.describe(config.run.name)}", file=out, flush=True)
                ignored = settings_not_applied(run_dir, config)
                if ignored:
                    print(f"hercs up: not applied, since nothing runs (its config.yaml is "
                          f"kept): {'; '.join(ignored)}", file=out, flush=True)
                return 0
            for note in plan.notes:  # e.g. a torn tail: said here, not only in replay-0.log
                print(f"hercs up: {note}", file=out, flush=True)
            first_epoch = plan.checkpoint_epoch + 1
        return _run(config, run_dir, command=command, stop_timeout_s=stop_timeout_s,
                    ready_timeout_s=ready_timeout_s, out=out, err=err, resume=resume,
                    first_epoch=first_epoch)
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
         resume: bool, first_epoch: int) -> int:
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
        files = RunDir(run_dir)
        files.logs.mkdir(parents=True, exist_ok=True)
        with native_output_to(files.router_log, out, err) as (out, err):
            launcher = Supervisor(config=config, run_dir=run_dir, signals=signals,
                                 command=command, stop_timeout_s=stop_timeout_s,
                                 ready_timeout_s=ready_timeout_s, out=out, err=err,
                                 first_epoch=first_epoch)
            status = 1
            tracking = None
            try:
                save_yaml(config, files.config)
                write_router(run_dir, RouterRecord.for_listen(listening))
                launcher.say(f"hercs up: {'resuming ' if resume else ''}run "
                             f"{config.run.name}, directory {run_dir}, router on {listening}")
                tracking = open_tracking(config, run_dir, say=lambda line: launcher.say(
                    f"hercs up: warning: {line}", error=True))
                if tracking is not None:  # its own threads: no tracker call can hold the run
                    launcher.say(f"hercs up: tracking to {', '.join(tracking.names)}")
                    tracking.follow()
                router.subscribe(launcher.keys.all_metrics, launcher.on_metrics)
                router.subscribe(launcher.keys.eval_result, launcher.on_eval)
                router.subscribe(launcher.keys.status, launcher.on_status, drop_oldest=True)
                router.subscribe(launcher.keys.inserted, launcher.on_inserted,
                                 drop_oldest=True)
                router.subscribe(launcher.keys.progress, launcher.on_run_progress,
                                 drop_oldest=True)
                router.watch_alive(launcher.keys.all_alive, launcher.on_alive)
                status = launcher.run()
            finally:
                launcher.stop_all()
                with launcher._print_lock:
                    launcher._say_all(launcher.progress.flush())
                router.close()
                remove_router(run_dir)
                if tracking is not None:  # after the learner's last row
                    tracking.close(complete=status == 0)
            if status == 0:
                launcher._say_all(launcher.progress.finished_lines(config.run.name, run_dir))
            else:
                launcher.say(f"hercs up: run {config.run.name} stopped; run directory: "
                             f"{run_dir}", error=status < 128)  # not on a signal: a failure
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
