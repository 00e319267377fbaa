"""`hercs up` owns its run directory (issue 33, items 2 and 6), with real launcher processes
and stand-in children (tests/integration/test_launcher.py's): a second `hercs up` on a running
run is refused at once naming the first; `--resume --restart` starts a run over with its old
files set aside; the embedded router's own Zenoh log goes to logs/router.log, not among the
progress lines."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from hercs.apps.cli.main import main
from hercs.run.metrics import recorded_epochs
from hercs.run.rundir import RunDir
from tests.integration.launcher_standins import STANDIN, Launcher
from tests.run_dirs import make_run
from tests.support import free_endpoint

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
WAIT_S = 60.0

# `hercs up ARGS` with the stand-ins as children (as test_launcher's DRIVER, with --resume).
DRIVER = r'''
import sys
from hercs.apps.cli.main import build_parser, resolve_config
from hercs.apps.launch.launcher import run_up
standin, events, behaviours = sys.argv[1:4]
args = build_parser()[0].parse_args(["up", *sys.argv[4:]])

def command(spec, config_path):
    return [sys.executable, standin, spec.role, spec.ident, str(config_path), events, behaviours]

sys.exit(run_up(resolve_config(args), command=command, stop_timeout_s=5.0,
                resume=bool(args.resume), restart=args.restart))
'''


def launch(tmp_path: Path, behaviours: str, *flags: str, env: dict[str, str] | None = None
           ) -> Launcher:
    (tmp_path / "standin.py").write_text(STANDIN)
    (tmp_path / "driver.py").write_text(DRIVER)
    argv = [sys.executable, str(tmp_path / "driver.py"), str(tmp_path / "standin.py"),
            str(tmp_path / "events.txt"), behaviours, "--listen", free_endpoint(), *flags]
    if env:
        os.environ.update(env)
    try:
        return Launcher(argv, cwd=tmp_path)
    finally:
        for key in env or {}:
            del os.environ[key]


def test_a_second_hercs_up_on_a_running_run_is_refused_naming_it(tmp_path: Path,
                                                                 capsys) -> None:
    first = launch(tmp_path, "{}", "--run", "busy", "--run-dir", str(tmp_path / "runs"),
                   "--actors", "0")
    run = tmp_path / "runs" / "busy"
    try:
        first.wait_for_line("run busy is running", timeout_s=WAIT_S)
        for argv in (["up", "--resume", str(run)],
                     ["up", "--run", "busy", "--run-dir", str(tmp_path / "runs")]):
            assert main(argv) == 2
            err = capsys.readouterr().err
            assert err.startswith(f"hercs up: {run} is in use by a running `hercs up` (pid "
                                  f"{first.proc.pid} on "), err
        assert first.proc.poll() is None  # the first one goes on
    finally:
        first.kill()


def test_restart_starts_the_run_over_with_its_old_files_set_aside(tmp_path: Path) -> None:
    run = tmp_path / "runs" / "again"
    make_run(run, epochs=2, trained=1, checkpoint=None)  # rows without a checkpoint
    RunDir(run).episode_log.write_bytes(b"the old run's episodes")
    old_metrics = RunDir(run).metrics.read_bytes()
    refused = launch(tmp_path, '{"learner-0": "epochs:2"}', "--resume", str(run))
    assert refused.finish(WAIT_S) == 2
    assert "no learner checkpoint" in "\n".join(refused.err) and not RunDir(run).logs.exists()

    again = launch(tmp_path, '{"learner-0": "epochs:2"}', "--resume", str(run), "--restart",
                   "--actors", "1")
    assert again.finish(WAIT_S) == 0, "\n".join(again.out + again.err)
    (aside,) = RunDir(run).previous.iterdir()
    assert again.out[0] == (f"hercs up: --restart: run again starts over from epoch 1; what "
                            f"it held is kept in {aside}")
    assert RunDir(aside).metrics.read_bytes() == old_metrics
    assert recorded_epochs(RunDir(aside).metrics) == [1]
    assert RunDir(aside).episode_log.read_bytes() == b"the old run's episodes"
    assert not RunDir(run).episode_log.exists() and not RunDir(run).metrics.exists()
    assert any(line.startswith("hercs up: resuming run again") for line in again.out)
    assert not RunDir(run).lock.exists()


def test_the_routers_own_log_goes_to_its_log_file_and_hercs_messages_to_the_terminal(
        tmp_path: Path) -> None:
    """RUST_LOG=debug makes the embedded router log every session it serves: all of that
    goes to logs/router.log once the run directory is there (before, only its start), while
    every line hercs prints (a child's failure and its log's tail included) still reaches
    the terminal.

    The learner serves until stopped: had it finished an epoch, a learner done before the
    clusterer's crash was seen would end the run as finished, with nothing on stderr (CI
    failed so once, under load)."""
    launcher = launch(tmp_path, '{"clusterer-0": "crash"}',
                      "--run", "chatty", "--run-dir", str(tmp_path / "runs"), "--actors", "0",
                      "--set", "launch.max_restarts=0",
                      env={"RUST_LOG": "debug"})
    status = launcher.finish(WAIT_S)
    run = tmp_path / "runs" / "chatty"
    log = (RunDir(run).router_log).read_text()
    assert "zenoh::" in log and "DEBUG" in log, log[:2000]
    running = next(i for i, line in enumerate(launcher.out) if "run chatty, directory" in line)
    printed = launcher.out[running:] + [line for line in launcher.err
                                        if not line.startswith("  | ")]  # a log's tail
    assert not [line for line in printed if "DEBUG" in line or "zenoh::" in line], printed
    assert launcher.err[-1] == f"hercs up: run chatty stopped; run directory: {run}"
    assert status == 1 and "boom: the stand-in failed on purpose" in "\n".join(launcher.err)


NATIVE = r'''
import os, sys
from pathlib import Path
from hercs.apps.launch.launcher import native_output_to
with native_output_to(Path(sys.argv[1]), sys.stdout, sys.stderr) as (out, err):
    os.write(1, b"native stdout line, as Zenoh's logger writes\n")
    os.write(2, b"native stderr line\n")
    print("hercs: a progress line", file=out)
    print("hercs: a message for the user", file=err)
    print("hercs: through sys.stdout")
    print("hercs: through sys.stderr", file=sys.stderr)
os.write(1, b"native after the block\n")
'''


def test_native_output_goes_to_the_file_and_pythons_to_the_terminal(tmp_path: Path) -> None:
    log = tmp_path / "router.log"
    done = subprocess.run([sys.executable, "-c", NATIVE, str(log)], cwd=REPO,
                          capture_output=True, text=True, timeout=WAIT_S)
    assert done.returncode == 0, done.stderr
    assert done.stdout == ("hercs: a progress line\nhercs: through sys.stdout\n"
                           "native after the block\n")
    assert done.stderr == "hercs: a message for the user\nhercs: through sys.stderr\n"
    assert log.read_text() == ("native stdout line, as Zenoh's logger writes\n"
                               "native stderr line\n")
