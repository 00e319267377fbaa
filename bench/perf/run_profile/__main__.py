"""`python -m bench.perf.run_profile [--quick] [--epochs N] [--out DIR]`: profile a run's every
process, and write run_profile.{json,md} and run_profile_cores.csv."""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench.common import (
    REPO,
    git_commit,
    machine_identity,
    parse_run_args,
    report_folder,
    show_report,
)
from bench.perf.run_profile.proc_sampler import ProcSampler
from bench.perf.run_profile.report import render
from bench.perf.run_profile.stacks import GROUPS, group_shares, parse_raw, role_of, top_frames
from hercs.apps.launch.child_process import signal_group
from hercs.run.metrics import read_rows
from hercs.run.rundir import RunDir


def usage_problem(args: argparse.Namespace) -> str | None:
    if args.epochs < 1 or args.rate < 1:
        return f"--epochs and --rate must be ≥ 1 (got {args.epochs}, {args.rate})"
    return None


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m bench.perf.run_profile",
                                     description=__doc__)
    parser.add_argument("--task", default="push")
    parser.add_argument("--method", default="her-cs")
    parser.add_argument("--epochs", type=int, default=10)
    parser.add_argument("--rate", type=int, default=50, help="py-spy samples per second")
    return parse_run_args(parser, argv, "run_profile", usage_problem, task="reach", epochs=1)


def py_spy() -> str:
    """py-spy's path (`pip install py-spy`, in the dev extra); a clear exit where it is not."""
    found = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(found).exists():
        sys.exit("bench.perf.run_profile: py-spy is not installed (pip install 'py-spy==0.4.2', "
                 "or `make install`, whose dev extra has it)")
    return found


# A profiler that dies of one of these crashed by itself: py-spy can segfault while it attaches
# to a process the run has just started (benfred/py-spy#724, #638, open at 0.4.2). A
# profiler stopped by SIGINT or SIGTERM was stopped on purpose and is not tried again.
CRASH_SIGNALS = frozenset({signal.SIGSEGV, signal.SIGBUS, signal.SIGABRT, signal.SIGILL})
PROFILER_TRIES = 3


def profiler_crashed(code: int) -> bool:
    """Whether a profiler exit code is a crash of its own (a death by a crash signal)."""
    return code < 0 and -code in CRASH_SIGNALS


def stop_group(child: subprocess.Popen[bytes], grace_s: float = 30.0) -> None:
    """Stop every process left in the profiler's session: when py-spy dies, the run it launched
    is orphaned and would train on beside whatever runs next. SIGTERM first, so `hercs up`
    stops its services in order; SIGKILL to whatever is left after `grace_s`."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        signal_group(child, sig)
        deadline = time.monotonic() + grace_s
        while time.monotonic() < deadline and group_alive(child.pid):
            time.sleep(0.2)
        if not group_alive(child.pid):
            return


def group_alive(pgid: int) -> bool:
    """Whether a live process is left in the group: a zombie is not (an orphan's zombie waits
    for a PID 1 that, in a container, may never reap it)."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rpartition(")")[2].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            return True
    return False


def run_under_profiler(spy: list[str], log: Path) -> tuple[int, ProcSampler, float]:
    """Run the profiler (which launches the run) in a session of its own, /proc sampled
    beside it; whatever is left in the session when it exits, however it exits, is stopped."""
    began = time.monotonic()
    with log.open("w") as out:
        child = subprocess.Popen(spy, cwd=REPO, stdout=out, stderr=subprocess.STDOUT,
                                 start_new_session=True)
        sampler = ProcSampler(root=child.pid)
        sampler.start()
        try:
            code = child.wait()
        finally:
            sampler.stop()
            stop_group(child)
    return code, sampler, time.monotonic() - began


def profile_run(args: argparse.Namespace, work: Path) -> dict[str, Any]:
    """Run `hercs up` under `py-spy record --subprocesses --native`, /proc sampled beside it;
    a run whose profiler crashes is stopped and profiled afresh, up to PROFILER_TRIES times."""
    crashes: list[str] = []
    for attempt in range(1, PROFILER_TRIES + 1):
        here = work / f"try-{attempt}"
        here.mkdir()
        raw = here / "stacks.txt"
        command = [sys.executable, "-m", "hercs.apps.cli", "up", "--task", args.task,
                   "--method", args.method, "--epochs", str(args.epochs), "--actors", "1",
                   "--run-dir", str(here / "runs"), "--listen", "tcp/127.0.0.1:0",
                   *(item for kv in args.set for item in ("--set", kv))]
        spy = [py_spy(), "record", "--subprocesses", "--native", "--format", "raw", "--rate",
               str(args.rate), "--output", str(raw), "--", *command]
        code, sampler, wall = run_under_profiler(spy, here / "up.log")
        runs = sorted((here / "runs").glob("*/"))
        if code == 0 and runs and raw.exists():
            break
        tail = (here / "up.log").read_text()[-3000:]
        if not profiler_crashed(code) or attempt == PROFILER_TRIES:
            sys.exit(f"bench.perf.run_profile: the profiled run failed (exit {code}, try "
                     f"{attempt} of {PROFILER_TRIES}):\n{tail}")
        crashes.append(signal.Signals(-code).name)
        print(f"bench.perf.run_profile: py-spy died of {crashes[-1]} on try {attempt} (a crash "
              "of py-spy's own, benfred/py-spy#724); its run is stopped and profiled afresh",
              file=sys.stderr)
    rows = read_rows(RunDir(runs[0]).metrics)
    processes = parse_raw(raw.read_text().splitlines())
    return {"command": " ".join(command[1:]), "wall_s": wall, "epochs": len(rows),
            "run_wall_s": float(rows[-1]["wall_s"]) if rows else float("nan"),
            "cores": sampler.cores, "cpu": sampler.process_cpu, "commands": sampler.commands,
            "samples": processes, "profiler_crashes": crashes}


def summarise(measured: dict[str, Any]) -> dict[str, Any]:
    """CPU seconds per epoch by process and by function group, idle and other load."""
    epochs = max(int(measured["epochs"]), 1)
    by_role: dict[str, float] = {}
    groups: dict[str, dict[str, float]] = {}
    frames: dict[str, list[tuple[str, float]]] = {}
    for pid, seconds in measured["cpu"].items():
        role = role_of(measured["commands"].get(pid, ""))
        if role == "other":
            continue  # py-spy itself
        by_role[role] = by_role.get(role, 0.0) + seconds / epochs
        samples = measured["samples"].get(pid)
        if samples is not None:
            # py-spy names a process by the command line it first saw, which for a service
            # caught between fork and exec is its launcher's: /proc's later reading wins
            samples.role = role
        shares = group_shares(samples) if samples is not None else {}
        for group, share in (shares or {"other": 1.0}).items():
            row = groups.setdefault(group, {})
            row[role] = row.get(role, 0.0) + share * seconds / epochs
        if samples is not None and samples.busy:
            frames[role] = top_frames(samples)
    cores = measured["cores"]
    n_cores = os.cpu_count() or 1
    machine_busy = sum(sum(s.values()) for _, s in cores) / max(len(cores), 1)
    per_epoch_wall = measured["wall_s"] / epochs
    run_cpu = sum(by_role.values())
    return {
        "epochs": epochs, "wall_s": measured["wall_s"], "run_wall_s": measured["run_wall_s"],
        "command": measured["command"], "cores": n_cores,
        "cpu_s_per_epoch_by_process": by_role,
        "cpu_s_per_epoch_by_group": {g: groups[g] for g in (*GROUPS, "other") if g in groups},
        "idle_s_per_epoch": max(n_cores - machine_busy, 0.0) * per_epoch_wall,
        "other_load_s_per_epoch": max(machine_busy * per_epoch_wall - run_cpu, 0.0),
        "core_busy_mean": {name: sum(s.get(name, 0.0) for _, s in cores) / max(len(cores), 1)
                           for name in (cores[0][1] if cores else {})},
        "top_frames": frames,
        "profiler_crashes": measured["profiler_crashes"],
    }


def write_cores(path: Path, cores: list[tuple[float, dict[str, float]]]) -> None:
    names = sorted(cores[0][1]) if cores else []
    lines = ["time_s," + ",".join(f"{n}_busy" for n in names)]
    lines += [f"{t:.2f}," + ",".join(f"{s.get(n, 0.0):.3f}" for n in names) for t, s in cores]
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="hercs-profile-") as tmp:
        measured = profile_run(args, Path(tmp))
    summary = summarise(measured)
    summary.update({"date": datetime.now(UTC).strftime("%Y-%m-%d"), "commit": git_commit(),
                    "machine": machine_identity(), "quick": args.quick, "rate": args.rate})
    show_report(args, "run_profile", summary, render(summary))
    out = report_folder(args.out, args.quick, REPO)
    if out is not None:
        write_cores(out / "run_profile_cores.csv", measured["cores"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
