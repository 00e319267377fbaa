"""Fault injection: a real `hercs up` run while each service in turn is SIGKILLed.

    python -m bench.faults.service_kills                 # ~10 min: FetchReach, 6 epochs per fault

One fresh run per fault; reported per fault (acked episodes lost, time to restart and to the
next epoch, `metrics.csv` rows, exit status) in docs/results/faults.{md,json}."""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import platform
import queue
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from bench.common import REPO, git_commit, table_with_notes
from hercs.apps.launch.child_process import pdeathsig_preexec
from hercs.apps.launch.router import free_port
from hercs.run.metrics import recorded_epochs
from hercs.run.rundir import RunDir
from hercs.run.runlog import read_episode_messages

FAULTS = ("replay", "learner", "clusterer", "evaluator", "actor", "everything")
CHILD = {"replay": "replay-0", "learner": "learner-0", "clusterer": "clusterer-0",
         "evaluator": "evaluator-0", "actor": "actor-1"}
STARTED = re.compile(r"^hercs up: started \w+ (?P<ident>[\w-]+)(?P<again> again)?.*\(pid "
                     r"(?P<pid>\d+)\)")
EPOCH = re.compile(r"^epoch (?P<epoch>\d+)/(?P<of>\d+)  success")  # not the "running" lines


@dataclass
class FaultResult:
    fault: str
    exit_status: int
    epochs_expected: int
    epochs_recorded: list[int]
    acked_before_kill: int
    lost: int
    restarted_after_s: float | None
    next_epoch_after_s: float | None
    median_epoch_s: float | None
    wall_s: float
    notes: list[str] = field(default_factory=list)

    @property
    def epochs_lost(self) -> int:
        return len(set(range(1, self.epochs_expected + 1)) - set(self.epochs_recorded))

    @property
    def epochs_twice(self) -> int:
        return len(self.epochs_recorded) - len(set(self.epochs_recorded))

    @property
    def ok(self) -> bool:
        return (self.exit_status == 0 and self.lost == 0 and self.epochs_lost == 0
                and self.epochs_twice == 0)


class Up:
    """`hercs up` as a child process, its stdout lines timestamped on a queue."""

    def __init__(self, argv: list[str], log_path: Path) -> None:
        self.lines: queue.Queue[tuple[float, str]] = queue.Queue()
        self.pids: dict[str, int] = {}
        self.ended = False
        """The output ended (the launcher exited); every later wait fails at once."""
        self.seen: list[tuple[float, str]] = []
        self._log = log_path.open("a")
        # the parent-death signal: a bench that dies (even by SIGKILL) takes its run with it
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     cwd=REPO, preexec_fn=pdeathsig_preexec())
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._log.write(line)
            self._log.flush()
            self.lines.put((time.monotonic(), line.rstrip("\n")))
        self.lines.put((time.monotonic(), ""))  # end of output

    def wait_for(self, pattern: re.Pattern[str], timeout_s: float) -> tuple[float, re.Match[str]]:
        deadline = time.monotonic() + timeout_s
        while True:
            if self.ended:
                raise RuntimeError(f"hercs up ended (status {self.proc.wait()}) before a line "
                                   f"matching {pattern.pattern!r}")
            try:
                at, line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise TimeoutError(f"no line matching {pattern.pattern!r} within "
                                   f"{timeout_s:g} s") from None
            self.seen.append((at, line))
            if m := STARTED.match(line):
                self.pids[m["ident"]] = int(m["pid"])
            if m := pattern.match(line):
                return at, m
            if line == "" and self.lines.empty():  # the end-of-output marker
                self.ended = True

    def finish(self, timeout_s: float) -> int:
        never = re.compile(r"(?!)")  # read to the end of the output
        with contextlib.suppress(RuntimeError):
            self.wait_for(never, timeout_s)
        status = self.proc.wait(timeout=timeout_s)
        self._log.close()
        return status

    def kill_all(self) -> None:
        """SIGKILL the launcher (and the router inside it), then every child it started (they
        run in process groups of their own)."""
        self.proc.kill()
        for pid in self.pids.values():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        self.proc.wait()


def distinct_episodes(run_dir: Path) -> set[tuple[str, int]]:
    return {(msg.actor_id, int(msg.seq)) for _, msg in read_episode_messages(run_dir)}


def epochs_recorded(run_dir: Path) -> list[int]:
    return recorded_epochs(RunDir(run_dir).metrics)


def epoch_times(seen: list[tuple[float, str]]) -> list[float]:
    stamps = [at for at, line in seen if EPOCH.match(line)]
    return [b - a for a, b in itertools.pairwise(stamps)]


def run_fault(fault: str, *, root: Path, epochs: int, cycles: int, kill_at: int,
              timeout_s: float, actors: int = 2) -> FaultResult:
    run = f"fault-{fault}"
    child = f"actor-{actors - 1}" if fault == "actor" else CHILD[fault]  # the last actor
    run_dir = root / run
    base = [sys.executable, "-m", "hercs.apps.cli", "up"]
    options = ["--listen", f"tcp/127.0.0.1:{free_port()}",
               "--set", f"training.epochs={epochs}",
               "--set", "launch.restart_backoff_s=0.5"]
    argv = [*base, "--task", "reach", "--method", "her-cs", "--actors", str(actors), "--seed", "1",
            "--run", run, "--run-dir", str(root),
            "--set", f"training.cycles_per_epoch={cycles}",
            "--set", "training.eval_episodes=5", "--set", "cluster.fgb_size=40", *options]
    started = time.monotonic()
    up = Up(argv, root / f"{run}.out")
    notes: list[str] = []
    up.wait_for(re.compile(rf"^epoch {kill_at}/\d+  success"), timeout_s)
    if fault == "everything":
        up.kill_all()
        killed_at = time.monotonic()
        acked = distinct_episodes(run_dir)
        up = Up([*base, "--resume", str(run_dir), *options], root / f"{run}.out")
        restarted_at, _ = up.wait_for(re.compile(r"^hercs up: resuming run"), timeout_s)
    else:
        os.kill(up.pids[child], signal.SIGKILL)
        killed_at = time.monotonic()
        if fault == "replay":  # its files are final now; a restarted replay seals them
            acked = distinct_episodes(run_dir)
        restarted_at, _ = up.wait_for(
            re.compile(rf"^hercs up: started \w+ {child} again"), timeout_s)
        if fault != "replay":
            # the live replay is still writing: what it holds now (all acked by now) is what
            # must survive; read its segments as they are (the reader tolerates the live tail)
            acked = distinct_episodes(run_dir)
    try:
        next_epoch_at, _ = up.wait_for(EPOCH, timeout_s)
        next_epoch_s: float | None = next_epoch_at - killed_at
    except (TimeoutError, RuntimeError) as exc:
        next_epoch_s = None
        notes.append(f"no epoch after the kill: {exc}")
    status = up.finish(timeout_s)
    final = distinct_episodes(run_dir)
    durations = epoch_times(up.seen)
    return FaultResult(
        fault=fault, exit_status=status, epochs_expected=epochs,
        epochs_recorded=epochs_recorded(run_dir), acked_before_kill=len(acked),
        lost=len(acked - final), restarted_after_s=round(restarted_at - killed_at, 2),
        next_epoch_after_s=None if next_epoch_s is None else round(next_epoch_s, 2),
        median_epoch_s=round(statistics.median(durations), 2) if durations else None,
        wall_s=round(time.monotonic() - started, 1), notes=notes)


def report(results: list[FaultResult], *, command: str, quick: bool) -> str:
    lines = [
        "# Fault injection: one SIGKILL per run",
        "",
        f"`{command}` — {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, commit {git_commit()}, "
        f"{platform.node()} ({os.cpu_count()} cores){' — QUICK MODE' if quick else ''}.",
        "",
        "Each row is a fresh FetchReach HER-CS run (2 actors) whose target was SIGKILLed right "
        "after the progress line of the kill epoch; `everything` kills the launcher "
        "(router inside) and all services and continues with `hercs up --resume`. Acked = "
        "distinct (actor, seq) in the episode log at the kill (the log is written before the "
        "ack); lost = those missing from the log at the end. Times are from the kill.",
        "",
        "Faults of the network between hosts (loss, a narrow link, latency, partitions; "
        "actors in network namespaces over TLS) are in [net_faults.md](net_faults.md) "
        "(`python -m bench.faults.net_faults`).",
        "",
        "| fault | exit | acked before kill | lost | epochs (expected) | missing / twice | "
        "restarted after | next epoch after | median epoch | wall | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r.fault} | {r.exit_status} | {r.acked_before_kill} | {r.lost} | "
            f"{len(r.epochs_recorded)} ({r.epochs_expected}) | {r.epochs_lost} / "
            f"{r.epochs_twice} | {r.restarted_after_s} s | {r.next_epoch_after_s} s | "
            f"{r.median_epoch_s} s | {r.wall_s} s | {'ok' if r.ok else 'FAILED'} |")
    return table_with_notes(lines, ((r.fault, note) for r in results for note in r.notes))


def kept_sections(path: Path) -> str:
    """The `## ` sections after the generated report in an existing faults.md (other faults'
    measurements, e.g. the replay's recovery time), kept when the report is written again."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return ""
    at = text.find("\n## ")
    return "" if at < 0 else text[at:]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--faults", nargs="+", choices=FAULTS, default=list(FAULTS))
    parser.add_argument("--epochs", type=int, default=6)
    parser.add_argument("--cycles", type=int, default=5, help="cycles per epoch")
    parser.add_argument("--kill-at", type=int, default=2, help="kill after this epoch's line")
    parser.add_argument("--timeout", type=float, default=600.0, help="per wait, seconds")
    parser.add_argument("--out", type=Path, help="where faults.md and faults.json go "
                        "(default docs/results; a temp folder with --quick)")
    parser.add_argument("--quick", action="store_true",
                        help="CI: the actor fault only, 6 short epochs, into a temp folder")
    args = parser.parse_args(argv)
    faults, epochs, cycles = args.faults, args.epochs, args.cycles
    tmp = tempfile.TemporaryDirectory(prefix="hercs-faults-")
    out = args.out or (Path(tmp.name) if args.quick else REPO / "docs" / "results")
    kill_at = args.kill_at
    actors = 2
    if args.quick:  # kill after epoch 1 of 6: epochs must end after the restart
        # one actor: the run cannot end without its new incarnation, so the restart is
        # always seen; with two, a short run could finish on the other actor's episodes
        # before the launcher restarts the killed one. Six epochs, not three: the rate
        # limiter lets an actor run ~4 cycles ahead of the learner, and of 3 epochs of 2
        # cycles an actor had inserted every episode by the end of epoch 1 (net_faults saw
        # this), so on a fast machine the run could end before the restart
        faults, epochs, cycles, kill_at, actors = ["actor"], 6, 2, 1, 1
    root = Path(tmp.name) / "runs"
    root.mkdir(parents=True)
    results = []
    for fault in faults:
        print(f"faults: {fault} …", flush=True)
        result = run_fault(fault, root=root, epochs=epochs, cycles=cycles,
                           kill_at=min(kill_at, epochs - 1), timeout_s=args.timeout,
                           actors=actors)
        print(f"faults: {fault}: {'ok' if result.ok else 'FAILED'} {asdict(result)}", flush=True)
        results.append(result)
    command = "python -m bench.faults.service_kills" + (" --quick" if args.quick else "")
    out.mkdir(parents=True, exist_ok=True)
    kept = kept_sections(out / "faults.md")
    (out / "faults.md").write_text(report(results, command=command, quick=args.quick) + kept)
    (out / "faults.json").write_text(json.dumps(
        [{**asdict(r), "ok": r.ok, "epochs_lost": r.epochs_lost, "epochs_twice": r.epochs_twice}
         for r in results], indent=2) + "\n")
    print(f"faults: wrote {out / 'faults.md'}")
    tmp.cleanup()
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
