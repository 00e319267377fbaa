"""Policy lag against epoch time over the asynchronous schedule's three lag sources.

    python -m bench.perf.lag_sources --beside       # each setting beside the first one's run

One real `hercs up` run per setting; `--beside` takes each ratio to a run started with it.
Writes docs/results/lag_sources.{json,md} (`--out`); method and results: docs/PERFORMANCE.md §2."""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

from bench.common import REPO, git_commit, machine_identity
from hercs.apps.launch.router import free_port
from hercs.run.metrics import read_rows
from hercs.run.rundir import RunDir


@dataclass(frozen=True)
class LagSetting:
    tolerance: float
    """replay.rate_tolerance_updates (minibatches; 40 = one cycle of updates)."""
    prefetch: int
    """learner.prefetch_depth."""
    queue: int
    """actor.insert_queue."""
    max_lag: int = -1
    """training.max_policy_lag (-1: no bound)."""

    @property
    def label(self) -> str:
        bound = "none" if self.max_lag < 0 else str(self.max_lag)
        return (f"tolerance {self.tolerance:g}, prefetch {self.prefetch}, queue {self.queue}, "
                f"bound {bound}")

    def overrides(self) -> list[str]:
        return [f"replay.rate_tolerance_updates={self.tolerance:g}",
                f"learner.prefetch_depth={self.prefetch}", f"actor.insert_queue={self.queue}",
                f"training.max_policy_lag={self.max_lag}"]


GRID = (
    LagSetting(80, 3, 2),      # the asynchronous default until 2026-11-25
    LagSetting(80, 1, 1),
    LagSetting(40, 1, 1),
    LagSetting(40, 0, 0),
    LagSetting(25, 1, 1),
    LagSetting(25, 0, 0),
    LagSetting(40, 1, 1, max_lag=2),
)
BESIDE_GRID = (LagSetting(80, 3, 2), LagSetting(40, 1, 1), LagSetting(40, 0, 0),
               LagSetting(25, 1, 1), LagSetting(25, 0, 0))
"""`--beside`: the candidates for the default (the smallest lags of the grid) and the old one."""
QUICK_GRID = (LagSetting(80, 3, 2), LagSetting(25, 0, 0, max_lag=1))
"""`--quick`: FetchReach, 3 epochs of 4 full-size cycles (40 updates per 4 episodes) with
minibatches of 1,024, so that the learner is the bottleneck by a wide margin and the lag sources
fill as in a real run. Smaller cycles left both settings' lags to the start-up race; with the
default 256 the old default's lag was still filling at epoch 3 (p95 3 and 5 beside two other
runs) and a CI run on a busier machine read 2 for both settings; with 1,024 it reaches its
cap of 7 in epoch 2."""


@dataclass
class LagRow:
    setting: LagSetting
    epoch_s: float
    epoch_ratio: float
    lag_mean: float
    lag_p50: float
    lag_p95: float
    lag_max: float
    epochs_used: int
    run_s: float


def summarise(rows: list[dict[str, str]]) -> dict[str, float]:
    """Epoch time and lag figures over the epochs after the first (all of them if only one)."""
    walls = [float(r["wall_s"]) for r in rows]
    times = [b - a for a, b in itertools.pairwise(walls)] or walls
    used = rows[1:] or rows

    def col(name: str) -> list[float]:
        return [float(r[name]) for r in used if r.get(name) not in (None, "", "nan")]

    def mean(values: list[float]) -> float:
        return statistics.fmean(values) if values else float("nan")

    return {"epoch_s": statistics.median(times), "lag_mean": mean(col("policy_lag")),
            "lag_p50": mean(col("policy_lag_p50")), "lag_p95": mean(col("policy_lag_p95")),
            "lag_max": max(col("policy_lag_max"), default=float("nan")),
            "epochs_used": len(used)}


def up_command(setting: LagSetting, *, task: str, epochs: int, cycles: int, root: Path,
               name: str, extra: list[str]) -> list[str]:
    cmd = [sys.executable, "-m", "hercs.apps.cli", "up", "--task", task, "--epochs", str(epochs),
           "--actors", "1", "--run", name, "--run-dir", str(root),
           "--listen", f"tcp/127.0.0.1:{free_port()}",
           "--set", f"training.cycles_per_epoch={cycles}"]
    for item in [*setting.overrides(), *extra]:
        cmd += ["--set", item]
    return cmd


def run_together(settings: list[LagSetting], *, root: Path, names: list[str],
                 **kwargs: object) -> list[tuple[dict[str, float], float]]:
    """Run `settings` at the same time; each one's figures and wall time."""
    started = time.monotonic()
    procs = []
    for setting, name in zip(settings, names, strict=True):
        log = (root / f"{name}.log").open("wb")
        cmd = up_command(setting, root=root, name=name, **kwargs)  # type: ignore[arg-type]
        procs.append((subprocess.Popen(cmd, cwd=REPO, stdout=log, stderr=subprocess.STDOUT),
                      log))
    out = []
    for (proc, log), name in zip(procs, names, strict=True):
        code = proc.wait()
        log.close()
        if code != 0:
            raise SystemExit(f"run {name} failed (exit {code}); log {root / (name + '.log')}")
        out.append((summarise(read_rows(RunDir(root / name).metrics)),
                    time.monotonic() - started))
    return out


def _row(setting: LagSetting, f: dict[str, float], base_s: float, run_s: float) -> LagRow:
    return LagRow(setting=setting, epoch_s=f["epoch_s"], epoch_ratio=f["epoch_s"] / base_s,
                  lag_mean=f["lag_mean"], lag_p50=f["lag_p50"], lag_p95=f["lag_p95"],
                  lag_max=f["lag_max"], epochs_used=int(f["epochs_used"]), run_s=run_s)


def markdown(rows: list[LagRow], meta: dict[str, object]) -> str:
    lines = [
        "# Policy lag against epoch time: the asynchronous schedule's lag sources",
        "",
        f"`{meta['command']}` — {meta['date']}, commit {meta['commit']}, "
        f"{meta['machine']}. Task {meta['task']}, method her-cs, one actor, {meta['epochs']} "
        f"epochs of {meta['cycles']} cycles per setting. {meta['mode']} {meta['note']} "
        "Epoch time: median over the epochs after the first. Lag: cycles "
        "behind the lockstep schedule (0 in lockstep), per-epoch p50/p95 averaged over the "
        "same epochs, max over them.",
        "",
        "| setting | epoch s | ratio | lag mean | p50 | p95 | max |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r.setting.label} | {r.epoch_s:.1f} | {r.epoch_ratio:.2f} | "
                     f"{r.lag_mean:.2f} | {r.lag_p50:.1f} | {r.lag_p95:.1f} | {r.lag_max:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="CI: two short FetchReach runs")
    p.add_argument("--task", default="push")
    p.add_argument("--epochs", type=int, default=4)
    p.add_argument("--cycles", type=int, default=25, help="cycles per epoch")
    p.add_argument("--beside", action="store_true",
                   help="run each setting beside a run of the first setting")
    p.add_argument("--note", default="", help="what else ran on the machine, for the report")
    p.add_argument("--out", default=None,
                   help="path stem of the .json/.md results (default "
                        "docs/results/lag_sources[_beside]; --quick: a temporary folder)")
    args = p.parse_args(argv)
    if args.epochs < 2 or args.cycles < 1:
        p.error(f"--epochs must be >= 2 and --cycles >= 1 (got {args.epochs}, {args.cycles})")
    grid: tuple[LagSetting, ...] = BESIDE_GRID if args.beside else GRID
    extra: list[str] = []
    if args.quick:
        grid, args.task, args.epochs, args.cycles = QUICK_GRID, "reach", 3, 4
        extra = ["training.eval_episodes=2", "ddpg.batch_size=1024"]
        if args.out is None:
            args.out = tempfile.mkdtemp(prefix="hercs-lag-") + "/lag_sources"
    root = Path(tempfile.mkdtemp(prefix="hercs-lag-runs-"))
    run_args = {"task": args.task, "epochs": args.epochs, "cycles": args.cycles,
                "extra": extra}
    rows = []
    if args.beside:  # each setting with a baseline run beside it: ratios within a pair
        for i, setting in enumerate(grid[1:], start=1):
            (base, _), (figures, run_s) = run_together(
                [grid[0], setting], root=root, names=[f"base{i}", f"lag{i}"], **run_args)
            print(f"{setting.label}: {json.dumps(figures)} beside {json.dumps(base)}",
                  flush=True)
            rows.append(_row(grid[0], base, base["epoch_s"], run_s))
            rows.append(_row(setting, figures, base["epoch_s"], run_s))
    else:
        measured = []
        for i, setting in enumerate([*grid, grid[0]]):  # the first again: the machine's drift
            ((figures, run_s),) = run_together([setting], root=root, names=[f"lag{i}"],
                                               **run_args)
            print(f"{setting.label}: {json.dumps(figures)} ({run_s:.0f} s)", flush=True)
            measured.append((setting, figures, run_s))
        base_s = statistics.fmean([measured[0][1]["epoch_s"], measured[-1][1]["epoch_s"]])
        rows = [_row(s, f, base_s, run_s) for s, f, run_s in measured]
    meta: dict[str, object] = {
        "command": "python -m bench.perf.lag_sources" + (" --quick" if args.quick else "")
                   + (" --beside" if args.beside else ""),
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "commit": git_commit(),
        "machine": machine_identity()["cpu"], "task": args.task, "epochs": args.epochs,
        "cycles": args.cycles, "note": args.note,
        "mode": ("Each setting ran beside a run of the first setting, started together; "
                 "ratio: its epoch time over that run's (the pair's first row has ratio 1)."
                 if args.beside else
                 "One run at a time; ratio to the mean of the first setting's two runs (the "
                 "first and the last row show the machine's drift).")}
    out = Path(args.out or str(REPO / "docs" / "results" / (
        "lag_sources_beside" if args.beside else "lag_sources")))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(
        {"meta": meta, "rows": [asdict(r) for r in rows]}, indent=2) + "\n")
    out.with_suffix(".md").write_text(markdown(rows, meta))
    print(f"wrote {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
