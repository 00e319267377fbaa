"""`hercs.up(...)`: start a whole run from Python and hold it by a handle.

The run is `hercs up` in a child process, so training never shares the caller's interpreter,
GIL or signals. Its config is built here as a tree, to what the command line builds from the
same choices, and handed to the child whole as a resolved YAML file (a bad value raises
`ConfigError` before anything starts). `rows()` yields metrics rows, `wait()` the exit
status, `policy("best")` the policy; `stop()` is Ctrl-C's orderly stop, also done when the
caller exits.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import io
import os
import queue
import re
import signal
import subprocess
import sys
import tempfile
import threading
import weakref
from collections import deque
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hercs.errors import ConfigError, HercsError

if TYPE_CHECKING:
    from hercs.api import Metrics, MetricValue, TrainedPolicy
    from hercs.config import HercsConfig

STOP_WAIT_S = 120.0
"""How long `stop()` waits for the orderly stop before it kills the run's processes."""
DEFAULT_LISTEN = "tcp/127.0.0.1:0"
"""`up()`'s router endpoint unless given: loopback, any free port."""
OUTPUT_LINES = 2000
"""The last lines of `hercs up`'s output a handle keeps (`Run.output`)."""
_EPOCH_LINE = re.compile(r"^epoch \d+/\d+  success ")
"""`hercs up`'s line for a finished epoch: its metrics.csv row is written by then."""
_OWNS_LINE = re.compile(r"^hercs up: (resuming )?run \S+, directory ")
"""`hercs up`'s first line once it holds the run's folder (a refused start never prints it)."""

_RUNNING: weakref.WeakSet[Run] = weakref.WeakSet()


def _stop_all_at_exit() -> None:
    """Ask every run to stop first, then wait for each: they stop side by side."""
    runs = list(_RUNNING)
    for run in runs:
        with contextlib.suppress(BaseException):
            run._signal_stop()
    for run in runs:
        with contextlib.suppress(BaseException):
            run.stop()


atexit.register(_stop_all_at_exit)


class _Spawner:
    """Starts child processes from one daemon thread that lives as long as the interpreter,
    so that a child's parent-death signal (sent when the thread that forked it ends) means
    "the caller's process is gone", not "the caller's worker thread finished"."""

    def __init__(self) -> None:
        self._requests: queue.Queue[tuple[list[str], queue.Queue[object]]] = queue.Queue()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    def popen(self, argv: list[str]) -> subprocess.Popen[str]:
        with self._lock:
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._serve, name="hercs-up-spawner",
                                                daemon=True)
                self._thread.start()
        answer: queue.Queue[object] = queue.Queue(maxsize=1)
        self._requests.put((argv, answer))
        result = answer.get()
        if isinstance(result, BaseException):
            raise result
        return result  # type: ignore[return-value]

    def _serve(self) -> None:
        from hercs.apps.launch.child_process import pdeathsig_preexec

        while True:
            argv, answer = self._requests.get()
            try:
                answer.put(subprocess.Popen(
                    argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                    bufsize=1, stdin=subprocess.DEVNULL,
                    # its own session: a Ctrl-C meant for the caller does not reach the
                    # services past `hercs up`'s orderly stop; stop() and the exit hook do
                    start_new_session=True, preexec_fn=pdeathsig_preexec(signal.SIGTERM)))
            except BaseException as exc:  # handed to the caller, who raises it
                answer.put(exc)


_SPAWNER = _Spawner()


def _built(task: str | None, method: str | None, epochs: int | None, seed: int | None,
           actors: int | None, name: str | None, run_dir: str | os.PathLike[str] | None,
           config: str | os.PathLike[str] | None,
           overrides: Mapping[str, Any] | Sequence[str], listen: str,
           track: str | Sequence[str] = ()) -> HercsConfig:
    """`up()`'s config, built as a tree in Python, in the command's order: the defaults, the
    YAML file, the named arguments, the trackers, then `overrides` (typed values from a dict,
    or "field=value" strings as `--set` takes them). Task names given here are trusted, as
    the command trusts those on its command line (hercs.rl.code_names)."""
    from hercs.apps.cli.config_flags import SHORTCUTS, trust_named_tasks
    from hercs.apps.tracking.flags import backends_override
    from hercs.config import HercsConfig, apply_overrides, load_yaml, with_values
    from hercs.rl.code_names import trust_task

    if isinstance(overrides, str):
        raise ConfigError(f"overrides: give a list of 'field=value' strings or a dict, not "
                          f"the string {overrides!r}")
    typed: Mapping[str, Any] | None = overrides if isinstance(overrides, Mapping) else None
    strings: list[str] = [] if typed is not None else list(overrides)
    # the command's flags by name, so that SHORTCUTS maps them to their fields as it does there
    flags = {"task": task, "method": method, "epochs": epochs, "seed": seed, "actors": actors,
             "run": name, "run_dir": None if run_dir is None else str(run_dir)}
    given: dict[str, Any] = {SHORTCUTS[flag]: value for flag, value in flags.items()
                             if value is not None}
    given["transport.listen"] = [listen]
    # trusted before any config is built, since building one resolves its task: the names
    # the command line would trust (task, the file's, --set task.name=), then a dict's
    trust_named_tasks(argparse.Namespace(task=task, config=str(config) if config else None,
                                         overrides=strings))
    typed_task = {str(key).strip(): value for key, value in (typed or {}).items()}.get(
        "task.name")
    if isinstance(typed_task, str) and typed_task:
        trust_task(typed_task)
    try:
        base = load_yaml(Path(config)) if config else HercsConfig()
        built = with_values(base, given)
        trackers = [track] if isinstance(track, str) else list(track)
        built = apply_overrides(built, backends_override(built.tracking.backends,
                                                         [str(t) for t in trackers]))
        if typed is not None:
            return with_values(built, typed)
        return apply_overrides(built, strings)
    except ConfigError as exc:
        raise ConfigError(f"hercs.up: {exc}") from None


def _checked(config: HercsConfig) -> HercsConfig:
    """`config` as the command would start it: its trackers installed, its run named."""
    from hercs.apps.launch.run_plan import default_run_name
    from hercs.apps.tracking.session import check_installed

    check_installed(config.tracking)  # as the command would refuse it, before it starts
    if not config.run.name:
        from hercs.config import with_values

        config = with_values(config, {"run.name": default_run_name(config)})
    return config


def _resolve(argv: list[str]) -> HercsConfig:
    """`hercs up ARGV`'s config, with its run name fixed: what the child will run (`resume`'s
    flags, which name a folder rather than a config)."""
    from hercs.apps.cli.main import build_parser, resolve_config

    parser = build_parser()[0]
    said = io.StringIO()
    try:
        with contextlib.redirect_stderr(said):
            args = parser.parse_args(["up", *argv])
    except SystemExit as exc:  # argparse's own message, without its usage lines
        why = (said.getvalue().strip().splitlines() or ["?"])[-1].partition("error: ")[2]
        raise ConfigError(f"hercs.up: arguments refused ({why}): {' '.join(argv)}") from exc
    return _checked(resolve_config(args))


def up(task: str | None = None, method: str | None = None, *, epochs: int | None = None,
       seed: int | None = None, actors: int | None = None, name: str | None = None,
       run_dir: str | os.PathLike[str] | None = None,
       config: str | os.PathLike[str] | None = None,
       overrides: Mapping[str, Any] | Sequence[str] = (), listen: str | None = None,
       track: str | Sequence[str] = ()) -> Run:
    """Start a run as `hercs up` would and return its handle.

    `task`, `method`, `epochs`, `seed`, `actors`, `name` (the run's name, else
    task-method-sSEED-time) and `run_dir` (the folder of runs, default `runs`) are the
    command's flags; `config` a YAML file; `overrides` what `--set` takes, as a list of
    "field=value" strings or a dict of typed values ({"ddpg.lr_actor": 5e-4}); `listen` the
    embedded router's endpoint: by default any free port on loopback, as the command's
    (tcp/127.0.0.1:0), so that several runs can go at once (other hosts join a TLS one:
    docs/python_api.md); `track` the trackers `--track` names ("wandb", or ["wandb",
    "mlflow"]). The config is built here as a tree (`hercs.config.with_values`) and handed
    to `hercs up` whole, as a resolved YAML file.
    Raises `ConfigError` (nothing started) for a bad value, as the command exits 2."""
    from hercs.config import save_yaml
    from hercs.run.rundir import holds_a_run

    resolved = _checked(_built(task, method, epochs, seed, actors, name, run_dir, config,
                               overrides, DEFAULT_LISTEN if listen is None else listen, track))
    folder = Path(resolved.run.run_dir) / resolved.run.name
    if holds_a_run(folder):
        raise ConfigError(f"hercs.up: {folder} already holds a run: give another name=, or "
                          f"continue that one with hercs.resume({str(folder)!r})")
    handed = tempfile.TemporaryDirectory(prefix="hercs-up-")
    path = Path(handed.name) / "config.yaml"
    save_yaml(resolved, path)
    return Run._start(["up", "--config", str(path)], folder, resolved.run.name, handed)


def resume(run_dir: str | os.PathLike[str], epochs: int | None = None) -> Run:
    """Continue a stopped run where it stopped, `hercs up --resume RUN_DIR`, to its own
    number of epochs or to `epochs`.

    Checks the folder as the command does before anything starts, and raises what it refuses
    (nothing started): `RunDirError` for a folder that is no run (missing, or without its
    config.yaml), `ConfigError` for a config that does not load or a bad `epochs`,
    `CannotResume` for files that would not let the run continue (a checkpoint that does not
    load, an episode log that is not one, metrics.csv and the checkpoint disagreeing). A run
    that already finished ends at once with exit 0 and says so (`Run.output`); one that
    another `hercs up` holds ends at once with exit 2 (`metrics` and `policy()` then raise
    HercsError)."""
    from hercs.apps.launch.resume_check import plan_resume
    from hercs.run.rundir import CONFIG, require_run_dir

    folder = Path(run_dir)
    require_run_dir(folder, needs=(CONFIG,))
    argv = ["--resume", str(folder), *(["--epochs", str(epochs)] if epochs is not None else [])]
    resolved = _resolve(argv)
    plan_resume(folder, epochs=resolved.training.epochs, config=resolved)
    return Run._start(["up", *argv], folder, folder.name)


class Run:
    """One `hercs up` started by `up()` (or `resume()`): its folder, its rows as they come,
    and the orderly stop. Methods are safe to call from several threads."""

    def __init__(self, proc: subprocess.Popen[str], run_dir: Path, name: str,
                 handed: tempfile.TemporaryDirectory[str] | None = None) -> None:
        self._proc = proc
        self._handed = handed  # the config file `up()` gave the command: gone once it ends
        self.dir = run_dir.absolute()
        """The run's folder (config.yaml, metrics.csv, checkpoints/, logs/)."""
        self.name = name
        self._output: deque[str] = deque(maxlen=OUTPUT_LINES)
        self._changed = threading.Condition()
        self._epoch_lines = 0
        self._ended = False
        self._owns = False  # `hercs up` said it holds the folder
        self._stop_sent = False
        self._reader = threading.Thread(target=self._read, name=f"hercs-up-{name}",
                                        daemon=True)
        self._reader.start()
        _RUNNING.add(self)

    @classmethod
    def _start(cls, argv: list[str], run_dir: Path, name: str,
               handed: tempfile.TemporaryDirectory[str] | None = None) -> Run:
        return cls(_SPAWNER.popen([sys.executable, "-m", "hercs.apps.cli", *argv]), run_dir,
                   name, handed)

    @property
    def output(self) -> list[str]:
        """The last lines `hercs up` printed (stdout and stderr, in order), as of now."""
        with self._changed:
            return list(self._output)

    # ------------------------------------------------------------------ watching

    def _read(self) -> None:
        assert self._proc.stdout is not None
        for line in self._proc.stdout:
            line = line.rstrip("\n")
            with self._changed:
                self._output.append(line)
                if _EPOCH_LINE.match(line):
                    self._epoch_lines += 1
                self._owns = self._owns or bool(_OWNS_LINE.match(line))
                self._changed.notify_all()
        self._proc.wait()
        if self._handed is not None:
            self._handed.cleanup()
        with self._changed:
            self._ended = True
            self._changed.notify_all()
        _RUNNING.discard(self)

    @property
    def running(self) -> bool:
        return self._proc.poll() is None

    @property
    def returncode(self) -> int | None:
        """The exit status of `hercs up` (0: finished; 130: stopped), None while running."""
        return self._proc.poll()

    def rows(self, timeout_s: float | None = None) -> Iterator[dict[str, MetricValue]]:
        """metrics.csv's rows, each once, as their epochs end (rows already there first);
        the iteration ends with the run. `timeout_s` bounds each wait for the next row
        (TimeoutError)."""
        seen = 0
        if not self._wait_owned(timeout_s):
            return  # refused: the folder is not this run's (`output` says why)
        while True:
            with self._changed:
                lines, ended = self._epoch_lines, self._ended
            metrics = self._read_metrics()
            rows = metrics.rows if metrics is not None else ()
            yield from rows[seen:]
            seen = max(seen, len(rows))
            if ended:
                return
            if not self._wait_past(lines, timeout_s):
                raise TimeoutError(f"run {self.name}: no epoch ended within {timeout_s} s")

    def _wait_owned(self, timeout_s: float | None) -> bool:
        """Until `hercs up` holds the run's folder (True) or ended without it (False)."""
        with self._changed:
            if not self._changed.wait_for(lambda: self._owns or self._ended, timeout_s):
                raise TimeoutError(f"run {self.name}: hercs up did not start within "
                                   f"{timeout_s} s")
            return self._owns

    def _refused(self) -> HercsError:
        tail = "\n".join(self.output[-5:])
        return HercsError(f"run {self.name}: hercs up did not start it (exit "
                          f"{self.returncode}); it said:\n{tail}")

    def _wait_past(self, lines: int, timeout_s: float | None) -> bool:
        """Until an epoch line after the first `lines` came, or the run ended."""
        with self._changed:
            return self._changed.wait_for(
                lambda: self._ended or self._epoch_lines > lines, timeout_s)

    def _read_metrics(self) -> Metrics | None:
        from hercs.api import read_metrics

        try:
            return read_metrics(self.dir)
        except HercsError:  # not written yet
            return None

    def wait(self, timeout_s: float | None = None) -> int:
        """Wait for the run to end; its exit status (0 once finished). TimeoutError if it
        is still going after `timeout_s`."""
        try:
            code = self._proc.wait(timeout_s)
        except subprocess.TimeoutExpired as exc:
            raise TimeoutError(f"run {self.name} still running after {timeout_s} s") from exc
        self._reader.join()
        return code

    def stop(self, timeout_s: float = STOP_WAIT_S) -> int:
        """The orderly stop (Ctrl-C's): the services stop in order, what was acknowledged
        stays and `resume()` continues from the last checkpoint. Past `timeout_s` the run's
        processes are killed. Returns the exit status; a run that ended already just gives
        its own."""
        self._signal_stop()
        try:
            self._proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self._proc.pid, signal.SIGKILL)
        return self.wait()

    def _signal_stop(self) -> None:
        """SIGINT once: a second one would tell `hercs up` to skip its orderly stop."""
        with self._changed:
            if self._stop_sent or self._proc.poll() is not None:
                return
            self._stop_sent = True
        with contextlib.suppress(ProcessLookupError):
            self._proc.send_signal(signal.SIGINT)

    def resume(self, epochs: int | None = None) -> Run:
        """Continue this (stopped) run where it stopped, `hercs up --resume`, to its own
        number of epochs or to `epochs`. A new handle; this one must have ended. A refused
        resume (nothing to continue from, a finished run) ends at once with the command's
        exit status and message (`output`)."""
        if self.running:
            raise HercsError(f"run {self.name} is still running; stop() it first")
        if not self._owns:
            raise self._refused()
        return resume(self.dir, epochs)

    # ------------------------------------------------------------------ results

    @property
    def metrics(self) -> Metrics:
        """metrics.csv as it is now (`hercs.read_metrics`); HercsError for a refused start."""
        from hercs.api import read_metrics

        if not self._owns and not self.running:
            raise self._refused()
        return read_metrics(self.dir)

    def policy(self, checkpoint: str = "best", **kw: Any) -> TrainedPolicy:
        """The trained policy (`hercs.load_policy`): "best", "latest" or a file name."""
        from hercs.api import load_policy

        if not self._owns and not self.running:
            raise self._refused()
        return load_policy(self.dir, checkpoint, **kw)

    def __repr__(self) -> str:
        state = "running" if self.running else f"ended ({self.returncode})"
        return f"<hercs.Run {self.name} {state} in {self.dir}>"

    def __enter__(self) -> Run:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
