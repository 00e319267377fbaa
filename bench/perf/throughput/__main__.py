"""`python -m bench.perf.throughput [--quick] [--out DIR]`: every figure of the package docstring,
phase after phase, into throughput.json and throughput.md."""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import signal
import sys
import tempfile
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

from bench.common import REPO
from bench.perf.throughput import (
    BenchError,
    env_steps,
    insert_rate,
    learner_updates,
    replay_memory,
    sample_latency,
    say,
)
from bench.perf.throughput import __doc__ as overview
from bench.perf.throughput.harness import Harness
from bench.perf.throughput.plan import FULL, QUICK
from bench.perf.throughput.throughput_report import build_report, write_report


def run(bench: Harness) -> None:
    with bench.phase("replay start"):
        replay = bench.start("replay", "bench-replay-her", "her")
        bench.wait_status(lambda s: True, what="the replay up", replay=replay)
        time.sleep(1.0)  # let start-up allocations settle before the idle reading
        idle = replay.memory_mib()
        say(f"idle replay RSS {idle['VmRSS']:.1f} MiB")
    # The replay's RSS after each phase, to see where its memory goes.
    trace = bench.details["replay_memory_mib_after"] = {"start": idle}
    with bench.phase("env steps"):
        env_steps.measure(bench)
    trace["env steps"] = replay.memory_mib()
    with bench.phase("learner updates"):
        learner_updates.measure(bench, replay)
    with bench.phase("learner roofline"):
        learner_updates.measure_roofline(bench)
    trace["learner updates"] = replay.memory_mib()
    with bench.phase("inserts"):
        insert_rate.measure(bench, replay)
    trace["inserts"] = replay.memory_mib()
    with bench.phase("fill"):
        episodes = bench.fill(replay)
    trace["fill"] = replay.memory_mib()
    with bench.phase("sample her"):
        sample_latency.measure(bench, "her", episodes)
        filled = replay.memory_mib()
    trace["sample her"] = filled
    bench.stop(replay)
    replay_memory.figures(bench, idle=idle, filled=filled, episodes=episodes)
    for method in bench.plan.methods[1:]:
        with bench.phase(f"sample {method}"):
            bench.status.clear()
            replay = bench.start("replay", f"bench-replay-{method}", method)
            bench.wait_status(lambda s: s.size_episodes >= episodes,
                             what=f"{episodes} episodes recovered from the log",
                             replay=replay)
            if bench.configs[method][0].run.uses_clusters:
                sample_latency.publish_cluster_model(bench, replay)
            sample_latency.measure(bench, method, episodes)
            bench.details.setdefault("replay_memory_mib_recovered", {})[method] = (
                replay.memory_mib())
            bench.stop(replay)
    with bench.phase("inserts without scenes"):
        insert_rate.measure_without_scenes(bench)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bench.perf.throughput",
                                description=(overview or "").split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true",
                   help="CI mode: tiny sizes and windows (well under a minute)")
    p.add_argument("--out", default=None,
                   help="folder for throughput.json and throughput.md (default docs/results; "
                        "a temporary folder with --quick)")
    p.add_argument("--keep-workdir", action="store_true",
                   help="keep the run folder (logs, episode log) even when all went well")
    return p


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    started, load_start = time.monotonic(), os.getloadavg()
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    command = shlex.join(["python", "-m", "bench.perf.throughput",
                          *(sys.argv[1:] if argv is None else argv)])
    plan = QUICK if args.quick else FULL
    out_dir = Path(args.out) if args.out else (
        Path(tempfile.mkdtemp(prefix="hercs-throughput-out-")) if args.quick
        else REPO / "docs" / "results")
    workdir = Path(tempfile.mkdtemp(prefix="hercs-throughput-"))
    signal.signal(signal.SIGTERM, _interrupt)  # so the finally blocks stop the children
    say(f"{plan.mode} mode; work folder {workdir}")
    ok = False
    try:
        with Harness(plan=plan, workdir=workdir) as bench:
            say(f"router on {bench.endpoint}")
            run(bench)
        report = build_report(plan=plan, figures=bench.figures, details=bench.details,
                              phase_wall_s=bench.phase_wall_s, command=command,
                              started=started, load_start=load_start, date=date)
        markdown = write_report(report, out_dir)
        ok = True
    except (BenchError, KeyboardInterrupt) as exc:
        say(f"stopped: {exc}")
        return 1
    finally:
        if ok and not args.keep_workdir:
            shutil.rmtree(workdir, ignore_errors=True)
        else:
            say(f"logs kept in {workdir / 'logs'}")
    print(markdown, end="")
    say(f"wrote {out_dir / 'throughput.json'} and {out_dir / 'throughput.md'} "
        f"({report['total_wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
