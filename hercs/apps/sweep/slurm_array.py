"""`hercs sweep --slurm`: one job array, one task per unfinished cell; each task runs the
sweep's own command for its cell (`--cell-index`), so resuming, the manifest and copying
finished runs work as they do locally."""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from hercs.errors import ConfigError


def cell_command(args: argparse.Namespace, tasks: Sequence[str], *, run_root: Path,
                 committed: Path | None, epochs: int, overrides: Sequence[str]) -> list[str]:
    """The sweep's command for one cell (`--cell-index` is appended by the array task)."""
    cmd = [sys.executable, "-m", "hercs.apps.cli", "sweep",
           "--tasks", *tasks,  # in the order given: the cell indices follow it
           "--methods", *args.methods,
           "--seeds", str(args.seeds), "--first-seed", str(args.first_seed),
           "--schedule", args.schedule,
           "--precision", args.precision, "--env-version", args.env_version,
           "--weld-torquescale", f"{args.weld_torquescale:g}",
           "--epochs", str(epochs),
           "--actors", str(args.actors), "--run-dir", str(run_root), "--jobs", "1"]
    if args.energy_epsilon is not None:
        cmd += ["--energy-epsilon", repr(args.energy_epsilon)]
    if committed is not None:
        cmd += ["--committed", str(committed)]
    for variant in args.variants:
        cmd += ["--variant", variant]
    if args.no_plain:
        cmd.append("--no-plain")
    for item in overrides:
        cmd += ["--set", item]
    return [*cmd, "--cell-index"]


def submit_slurm(args: argparse.Namespace, names: Sequence[str], todo: Sequence[int], *,
                 tasks: Sequence[str], run_root: Path, committed: Path | None, epochs: int,
                 overrides: Sequence[str]) -> int:
    """Submit the unfinished cells `todo` (indices into `names`) as one job array
    (hercs.apps.deploy.slurm)."""
    from hercs.apps.deploy.slurm import ArrayPlan, render_array_script, submit_array

    if not todo:
        print(f"every cell is finished; nothing to submit (hercs sweep report {run_root})")
        return 0
    try:
        plan = ArrayPlan(name=f"hercs-sweep-{run_root.name}", folder=run_root / "_slurm",
                         command=tuple(cell_command(args, tasks, run_root=run_root,
                                                    committed=committed, epochs=epochs,
                                                    overrides=overrides)),
                         indices=tuple(todo), cpus=args.slurm_cpus, time=args.slurm_time,
                         signal_before_s=args.slurm_signal_before,
                         partition=args.slurm_partition, account=args.slurm_account,
                         sbatch=tuple(args.slurm_sbatch), workdir=Path.cwd())
        script, job = submit_array(plan, dry_run=args.dry_run)
    except ConfigError as exc:
        print(f"hercs sweep: {exc}", file=sys.stderr)
        return 2
    if job is None:
        print(render_array_script(plan), end="")
        return 0
    listed = ", ".join(f"{i}: {names[i]}" for i in todo)
    print(f"array job {job}: {len(todo)} tasks ({listed}); script {script}; when they are "
          f"done: hercs sweep report {run_root}", flush=True)
    return 0


def run_one_cell(run: Callable[[], Sequence[tuple[object, int]]]) -> int:
    """An array task: `run` its one cell. SIGTERM (Slurm's stop) stops the run in order, as
    Ctrl-C does; the next attempt resumes it."""
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        results = run()
    except KeyboardInterrupt:
        return 128 + signal.SIGTERM
    return 1 if any(code != 0 for _, code in results) else 0
