"""A whole run's speed with `--workers N`, the learner on the GPU or the CPU (PERFORMANCE §7).

    python -m bench.perf.workers_e2e                      # on a CUDA machine: ~8 min

Each spec `N:DEVICE:EPOCHS` is one `hercs up --workers N --set learner.device=DEVICE` run. Writes
docs/results/workers_e2e.{json,md} (or --out DIR); results: docs/PERFORMANCE.md §7."""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from statistics import median
from typing import Any

from bench.common import REPO, git_commit
from hercs.api import read_metrics
from hercs.run.rundir import RunDir

DEFAULT_SPECS = ("1:cuda:3", "8:cuda:3", "1:cpu:3", "8:cpu:1")
METRICS_NAME = re.compile(r"^w(\d+)-([a-z0-9:]+?)(?:-([A-Za-z0-9_]+))?-metrics\.csv$")


@dataclass(frozen=True)
class Spec:
    workers: int
    device: str
    epochs: int

    @classmethod
    def parse(cls, text: str) -> Spec:
        parts = text.split(":")
        if len(parts) < 3:
            raise argparse.ArgumentTypeError(f"spec {text!r}: expected WORKERS:DEVICE:EPOCHS")
        workers, epochs = parts[0], parts[-1]
        device = ":".join(parts[1:-1])
        if not (workers.isdigit() and int(workers) >= 1 and epochs.isdigit() and int(epochs) >= 1):
            raise argparse.ArgumentTypeError(
                f"spec {text!r}: WORKERS and EPOCHS must be integers >= 1")
        if device.split(":")[0] not in ("cpu", "cuda", "auto"):
            raise argparse.ArgumentTypeError(f"spec {text!r}: DEVICE must be cpu, cuda[:N] or auto")
        return cls(int(workers), device, int(epochs))


@dataclass
class RunSummary:
    name: str
    workers: int
    device: str
    epochs: int
    epoch_s: float
    episodes_per_epoch: float
    episodes_per_s: float
    updates_per_s: float
    lag_p50: float
    lag_p95: float


def summarise(name: str, workers: int, device: str,
              rows: Sequence[Mapping[str, Any]]) -> RunSummary:
    """One run's figures from its metrics.csv rows (`hercs.read_metrics(...).rows`; epoch times
    from the cumulative wall_s)."""
    if not rows:
        raise ValueError(f"{name}: metrics.csv has no finished epoch")
    walls = [float(r["wall_s"]) for r in rows]
    epoch_times = [b - a for a, b in zip([0.0, *walls[:-1]], walls, strict=True)]
    episodes = [int(r["episodes"]) for r in rows]
    per_epoch = [b - a for a, b in zip([0, *episodes[:-1]], episodes, strict=True)]
    epoch_s = median(epoch_times)
    eps = median(per_epoch)
    return RunSummary(
        name=name, workers=workers, device=device, epochs=len(rows), epoch_s=round(epoch_s, 2),
        episodes_per_epoch=eps, episodes_per_s=round(eps / epoch_s, 2),
        updates_per_s=round(median(float(r["updates_per_s"]) for r in rows), 1),
        lag_p50=median(float(r["policy_lag_p50"]) for r in rows),
        lag_p95=median(float(r["policy_lag_p95"]) for r in rows))


def run_spec(spec: Spec, run_dir: Path, timeout_s: float, extra: list[str],
             keep: Path | None, repeat: int = 0) -> RunSummary | None:
    """`hercs up` for one spec; stopped with SIGINT (a clean stop) at timeout_s. A spec given
    again runs again under the name `w<N>-<device>-repeat<k>`."""
    name = f"w{spec.workers}-{spec.device.replace(':', '')}" + (
        f"-repeat{repeat}" if repeat else "")
    cmd = [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "push", "--method", "her-cs",
           "--seed", "1", "--epochs", str(spec.epochs), "--workers", str(spec.workers),
           "--set", f"learner.device={spec.device}", "--run-dir", str(run_dir), "--run", name,
           *extra]
    log = (run_dir / f"{name}.log").open("w")
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    log.close()
    metrics = RunDir(run_dir / name).metrics
    rows = read_metrics(metrics).rows if metrics.exists() else ()
    print(f"{name}: exit {proc.returncode}, {len(rows)} epochs", flush=True)
    if keep is not None and metrics.exists():
        shutil.copy(metrics, keep / f"{name}-metrics.csv")
    return summarise(name, spec.workers, spec.device, rows) if rows else None


def ratios(runs: list[RunSummary]) -> list[dict[str, object]]:
    """Episodes per second at N workers over 1 worker (same device), and CPU over GPU epoch
    time (same N); from the first run of each (workers, device)."""
    first: dict[tuple[int, str], RunSummary] = {}
    for r in runs:
        first.setdefault((r.workers, r.device.split(":")[0]), r)
    out: list[dict[str, object]] = []
    for (workers, device), r in sorted(first.items()):
        one = first.get((1, device))
        if workers > 1 and one is not None:
            out.append({"what": f"episodes/s, {workers} workers over 1, learner on {device}",
                        "ratio": round(r.episodes_per_s / one.episodes_per_s, 2)})
    for (workers, device), r in sorted(first.items()):
        gpu = first.get((workers, "cuda"))
        if device == "cpu" and gpu is not None:
            out.append({"what": f"epoch time, learner on the CPU over the GPU, {workers} "
                                f"worker{'s' if workers > 1 else ''}",
                        "ratio": round(r.epoch_s / gpu.epoch_s, 2)})
    return out


def render(result: dict) -> str:
    lines = ["# `hercs up --workers N` with the learner on the GPU and on the CPU", "",
             f"`python -m bench.perf.workers_e2e` — {result['when']}, commit {result['commit']}, "
             f"{result['machine']}. FetchPush-v4, HER-CS, seed 1, the reference schedule "
             "(N×4 episodes and 40 updates of N×256 transitions per cycle, 50 cycles per "
             "epoch); the learner's default one torch thread on the CPU. Median over each "
             "run's epochs.", ""]
    if result.get("note"):
        lines += [result["note"], ""]
    lines += ["| run | workers | learner | epochs | s per epoch | episodes per epoch | "
              "episodes/s | updates/s | lag p50 | lag p95 |", "|---" * 10 + "|"]
    for r in result["runs"]:
        lines.append(f"| {r['name']} | {r['workers']} | {r['device']} | {r['epochs']} | "
                     f"{r['epoch_s']:.1f} | {r['episodes_per_epoch']:.0f} | "
                     f"{r['episodes_per_s']:.1f} | {r['updates_per_s']:.0f} | {r['lag_p50']:g} | "
                     f"{r['lag_p95']:g} |")
    if result["ratios"]:
        lines += ["", "| ratio | value |", "|---|---|"]
        lines += [f"| {x['what']} | {x['ratio']}× |" for x in result["ratios"]]
    return "\n".join(lines) + "\n"


def machine() -> str:
    text = f"{platform.node()} ({os.cpu_count()} cores)"
    try:
        import torch
        if torch.cuda.is_available():
            text += f", GPU: {torch.cuda.get_device_name(0)}, torch {torch.__version__}"
    except ImportError:
        pass
    return text


def runs_from_dir(folder: Path) -> list[RunSummary]:
    runs = []
    for path in sorted(folder.iterdir()):
        m = METRICS_NAME.match(path.name)
        if m:
            name = path.name.removesuffix("-metrics.csv")
            runs.append(summarise(name, int(m.group(1)), m.group(2), read_metrics(path).rows))
    if not runs:
        raise SystemExit(f"--report {folder}: no w<N>-<device>[-tag]-metrics.csv there")
    return runs


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--spec", nargs="+", type=Spec.parse, default=None,
                   help=f"WORKERS:DEVICE:EPOCHS runs, in order (default {' '.join(DEFAULT_SPECS)})")
    p.add_argument("--timeout", type=float, default=240.0, help="seconds per run before a stop")
    p.add_argument("--quick", action="store_true", help="5 cycles per epoch (CI)")
    p.add_argument("--report", type=Path, help="only build the report from metrics files here")
    p.add_argument("--note", default="", help="a line for the report (where the runs came from)")
    p.add_argument("--when", default=None, help="the report's date line, for --report")
    p.add_argument("--machine", default=None, help="the report's machine line, for --report")
    p.add_argument("--out", type=Path, default=None, help="folder for workers_e2e.{json,md}")
    args = p.parse_args(argv)

    if args.report is not None:
        runs = runs_from_dir(args.report)
    else:
        specs = args.spec or [Spec.parse(s) for s in DEFAULT_SPECS]
        extra = ["--set", "training.cycles_per_epoch=5"] if args.quick else []
        runs = []
        with tempfile.TemporaryDirectory(prefix="hercs-workers-") as tmp:
            keep = args.out
            if keep is not None:
                keep.mkdir(parents=True, exist_ok=True)
            for i, spec in enumerate(specs):
                summary = run_spec(spec, Path(tmp), args.timeout, extra, keep,
                                   repeat=specs[:i].count(spec))
                if summary is not None:
                    runs.append(summary)
        if not runs:
            print("no run finished an epoch", file=sys.stderr)
            return 1
    result = {
        "when": args.when or datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": git_commit(), "machine": args.machine or machine(), "note": args.note,
        "runs": [asdict(r) for r in runs], "ratios": ratios(runs)}
    text = render(result)
    print(text)
    folder = args.out or (None if args.quick else REPO / "docs" / "results")
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "workers_e2e.json").write_text(json.dumps(result, indent=1) + "\n")
        (folder / "workers_e2e.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
