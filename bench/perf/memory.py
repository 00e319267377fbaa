"""Memory of each service over a long run: RSS sampled from /proc while the run trains.

    python -m bench.perf.memory RUN_DIR [RUN_DIR ...]  # samples until those runs end

`--report` writes docs/results/memory.md from the CSVs, flagging a role that grows beyond its
store (`GROWTH_FLAG_MB`): every service but the replay should stay flat once warm."""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from bench.common import REPO
from hercs.config import HercsConfig
from hercs.run.metrics import read_rows
from hercs.run.rundir import RunDir
from hercs.wire.episode import expected_shapes

OUT = REPO / "docs" / "results" / "memory"
GROWTH_FLAG_MB = 5.0
"""Late growth, in MB per 10 epochs beyond the store's own, that the report flags."""
MIN_SERVICE_RSS_MB = 1.0
"""Below this a process is mid-exec or exiting, not a running service (the interpreter alone
holds several MB)."""
COLUMNS = ("time_s", "epoch", "role", "pid", "rss_mb")


def run_processes(run_dir: Path) -> dict[int, str]:
    """pid → role of the processes of the run in `run_dir` (the launcher is 'up')."""
    config_path = str(RunDir(run_dir).config).encode()
    name = run_dir.name.encode()
    found: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"hercs.apps.cli" not in argv:
            continue
        at = argv.index(b"hercs.apps.cli") + 1
        command = argv[at].decode() if at < len(argv) else ""
        if config_path in argv:
            found[int(entry.name)] = command
        elif command == "up" and (str(run_dir).encode() in argv  # `up --resume RUN_DIR`
                                  or (b"--run" in argv
                                      and argv[argv.index(b"--run") + 1] == name)):
            found[int(entry.name)] = "up"
    return found


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def sample(run_dirs: list[Path], out: Path, every_s: float) -> None:
    """Append a row per process of each run every `every_s` s until every run has ended."""
    out.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    files = {}
    for run_dir in run_dirs:
        path = out / f"{run_dir.name}.csv"
        new = not path.exists()
        handle = open(path, "a", newline="")  # noqa: SIM115 (closed below)
        writer = csv.writer(handle)
        if new:
            writer.writerow(COLUMNS)
        files[run_dir] = (handle, writer)
    live = set(run_dirs)
    seen: set[Path] = set()
    while live:
        for run_dir in list(live):
            processes = run_processes(run_dir)
            if processes:
                seen.add(run_dir)
            elif run_dir in seen or time.monotonic() - start > 600:
                live.discard(run_dir)  # ended (or never started within 10 min)
                continue
            epoch = len(read_rows(RunDir(run_dir).metrics))
            handle, writer = files[run_dir]
            for pid, role in sorted(processes.items()):
                rss = rss_mb(pid)
                # None: gone; under 1 MB: between address spaces (in its exec, or exiting and
                # not yet reaped; a few kB, which would print as 0.0). A running Python service
                # holds tens of MB, so neither is a sample of its memory
                if rss is not None and rss >= MIN_SERVICE_RSS_MB:
                    writer.writerow((f"{time.monotonic() - start:.0f}", epoch, role, pid,
                                     f"{rss:.1f}"))
            handle.flush()
        time.sleep(every_s)
    for handle, _ in files.values():
        handle.close()


def store_mb_per_episode(config: HercsConfig) -> float:
    """Bytes the replay's store holds per FetchPush episode (float32 arrays), in MB."""
    shapes = expected_shapes(config.task.spec)
    return sum(int(np.prod(s)) for s in shapes.values()) * 4 / 1e6


def summarize(csv_path: Path) -> list[dict[str, object]]:
    rows = list(csv.DictReader(csv_path.read_text().splitlines()))
    by_role: dict[str, list[tuple[int, float]]] = defaultdict(list)
    for r in rows:
        by_role[r["role"]].append((int(r["epoch"]), float(r["rss_mb"])))
    run_dir_candidates = [REPO / "runs" / "sample_efficiency" / csv_path.stem,
                          REPO / "docs" / "results" / "runs" / csv_path.stem]
    config = HercsConfig()
    for candidate in run_dir_candidates:
        if RunDir(candidate).config.is_file():
            from hercs.config import load_yaml

            config = load_yaml(RunDir(candidate).config)
            break
    per_episode = store_mb_per_episode(config)
    episodes_per_epoch = config.training.cycles_per_epoch * config.training.episodes_per_cycle
    full_epoch = config.capacity_episodes / max(episodes_per_epoch, 1)
    out = []
    for role, points in sorted(by_role.items()):
        epochs = np.array([e for e, _ in points], float)
        rss = np.array([m for _, m in points], float)
        last, first = epochs.max(), epochs.min()
        late = epochs >= first + (last - first) / 2
        slope = (np.polyfit(epochs[late], rss[late], 1)[0] * 10
                 if late.sum() >= 3 and np.ptp(epochs[late]) > 0 else float("nan"))
        expected = per_episode * episodes_per_epoch * 10 if role == "replay" and \
            last < full_epoch else 0.0
        out.append({"role": role, "epochs": f"{first:.0f}–{last:.0f}", "first": rss[0],
                    "end": rss[-1], "peak": rss.max(), "slope": slope, "expected": expected,
                    "flag": bool(np.isfinite(slope) and slope - expected > GROWTH_FLAG_MB)})
    return out


def report(out: Path) -> str:
    lines = ["# Memory of each service over long runs", "",
             f"`python -m bench.perf.memory --report` — {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, "
             "from "
             f"the samples in `{out.relative_to(REPO) if out.is_relative_to(REPO) else out}/` "
             "(RSS from /proc every 30 s while the run trained; `python -m bench.perf.memory "
             "RUN_DIR` attaches to a running run). 'late slope': a straight line through "
             "the samples of the last half of the sampled epochs, MB per 10 epochs; 'store "
             "growth': what the replay must add per 10 epochs while its buffer fills (float32 "
             "episodes; 0 for every other role and once the buffer is full).", "",
             "| run | role | epochs sampled | first (MB) | end (MB) | peak (MB) | late slope "
             "(MB/10 ep) | store growth (MB/10 ep) | grows beyond its data? |",
             "|---|---|---|---|---|---|---|---|---|"]
    for csv_path in sorted(out.glob("*.csv")):
        for r in summarize(csv_path):
            lines.append(f"| {csv_path.stem} | {r['role']} | {r['epochs']} | {r['first']:.0f} | "
                         f"{r['end']:.0f} | {r['peak']:.0f} | {r['slope']:+.1f} | "
                         f"{r['expected']:.1f} | {'**yes**' if r['flag'] else 'no'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dirs", nargs="*", type=Path, help="runs to sample (running now)")
    parser.add_argument("--every", type=float, default=30.0, help="seconds between samples")
    parser.add_argument("--out", type=Path, default=OUT, help="where <run>.csv and the "
                        "report go (default docs/results/memory/)")
    parser.add_argument("--report", action="store_true", help="write the report and exit")
    parser.add_argument("--quick", action="store_true",
                        help="CI: sample a 4-epoch FetchReach run started here")
    args = parser.parse_args(argv)
    if args.quick:
        root = Path(tempfile.mkdtemp(prefix="hercs-memory-"))
        out = args.out if args.out != OUT else root / "memory"
        proc = subprocess.Popen(
            [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--epochs", "4",
             "--run", "memory-quick", "--run-dir", str(root), "--set",
             "training.cycles_per_epoch=3", "--set", "training.eval_episodes=2"],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # every 0.25 s over 4 epochs: a sample after epoch 1 however fast the machine runs
        # the rest (2 epochs sampled every 1 s could end between two samples)
        sample([root / "memory-quick"], out, 0.25)
        if proc.wait(timeout=600) != 0:
            print("bench.perf.memory --quick: the run failed", file=sys.stderr)
            return 1
        text = report(out)
        (out / "memory.md").write_text(text)
        print(text)
        return 0
    if args.run_dirs:
        sample([d.resolve() for d in args.run_dirs], args.out, args.every)
    text = report(args.out)
    print(text)
    (args.out.parent / "memory.md" if args.out == OUT else args.out / "memory.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
