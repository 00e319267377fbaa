"""`hercs sweep`: a grid of runs, tasks × methods × seeds × variants, each a full `hercs up`;
and `hercs sweep report`, its learning curves and its claims table (docs/GUIDE.md, "Grids of
runs").

Resumable: a finished run (`bench_done.json`) is skipped, an unfinished or shorter one is
continued from its checkpoint (a sweep grows). Runs go `--jobs` at a time, one per core by
default (each is bound by its learner's one torch thread), seed-major so every arm has as many
finished seeds as early as possible (`<run-dir>/sweep.json`). `--committed DIR` keeps each
finished run's small files to commit, which the report reads when a run is not local;
`--slurm` submits a job array (hercs.apps.sweep.slurm_array).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from hercs.apps.deploy.slurm import add_sbatch_arguments
from hercs.apps.output_paths import OutputPathError, check_output_folder
from hercs.apps.sweep.cells import (
    PROG,
    cannot_grow,
    cell_state,
    dry_run_lines,
    epsilon_changed,
    owned_override,
    parse_variant,
    plan_grid,
    write_manifest,
)
from hercs.apps.sweep.learner_stack import LEARNER_ELSEWHERE
from hercs.apps.sweep.report import main_report, write_reports
from hercs.apps.sweep.runner import run_grid
from hercs.apps.sweep.slurm_array import run_one_cell, submit_slurm
from hercs.apps.tracking.flags import add_track_argument, backends_override
from hercs.apps.tracking.session import check_installed
from hercs.config import PRECISIONS, SCHEDULES, HercsConfig, RunConfig, apply_overrides
from hercs.config.algorithm import EPSILON_MUJOCO3, EPSILON_V1
from hercs.errors import ConfigError
from hercs.rl.envs import check_env
from hercs.rl.methods import METHODS
from hercs.rl.task_registry import ENV_VERSIONS, TASKS, task_spec

QUICK_OVERRIDES = ("training.cycles_per_epoch=2", "training.episodes_per_cycle=2",
                   "training.minibatches_per_cycle=2", "training.eval_episodes=2")
"""A run that exercises every part (rollouts, inserts, sampling, updates, eval) in seconds."""
DEFAULT_METHODS = (next(iter(METHODS)), RunConfig.method)
"""A sweep's arms unless --methods says: the methods table's first (plain HER, the baseline)
and the config's default method."""



def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                                epilog="`hercs sweep report RUN_DIR` writes the report of a "
                                       "sweep from its manifest (--help there).",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=None, metavar="TASK",
                   help=f"tasks: Fetch presets {sorted(TASKS)} or any task.name, e.g. "
                        "HandReach-v3 (default: push; reach with --quick)")
    p.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(DEFAULT_METHODS),
                   help="the arms (default: the methods table's first, the baseline, and "
                        f"run.method's default: {' '.join(DEFAULT_METHODS)})")
    p.add_argument("--seeds", type=int, default=3,
                   help="how many seeds: S..S+N-1 for --first-seed S (default 3)")
    p.add_argument("--first-seed", type=int, default=1, metavar="S",
                   help="the first seed (default 1): more seeds for a grid whose first ones "
                        "are finished, e.g. --first-seed 7 --seeds 6 for seeds 7..12")
    p.add_argument("--schedule", choices=SCHEDULES, default="async",
                   help="training.schedule of every run (default async; lockstep runs are "
                        "named T-M-lockstep-sS)")
    p.add_argument("--precision", choices=PRECISIONS, default="fp32",
                   help="learner.precision of every run (default fp32; bf16 runs are named "
                        "T-M-bf16-sS)")
    p.add_argument("--env-version", choices=list(ENV_VERSIONS), default="v4",
                   help="task.env_version of every run (default v4; v1, the authors' Fetch*-v1 "
                        "on mujoco-py after `make mujoco-py`: runs named T-v1-M-sS)")
    p.add_argument("--energy-epsilon", type=float, default=None,
                   help="energy.epsilon of every run (EBP's floor added to every trajectory "
                        f"energy; default: the environment's, {EPSILON_MUJOCO3:g} on v4, "
                        f"{EPSILON_V1:g} on v1, docs/DESIGN.md §9.3). An EBP run whose ε is "
                        f"not {EPSILON_V1:g} is named T-eps1e-3-M-sS")
    p.add_argument("--weld-torquescale", type=float, default=1.0,
                   help="task.weld_torquescale of every run (v4 only; default 1, MuJoCo 3's; "
                        "4 tilts the gripper as v1 does, docs/results/env_diff.md: runs named "
                        "T-ts4-M-sS)")
    p.add_argument("--variant", dest="variants", action="append", default=[],
                   metavar="NAME:FIELD=VALUE[,FIELD=VALUE...]",
                   help="another arm: every task × method × seed again with these overrides, "
                        "runs named T-M-NAME-sS (repeat for more arms; the plain arm stays "
                        "unless --no-plain)")
    p.add_argument("--no-plain", action="store_true",
                   help="with --variant: only the variants' arms, not the plain one")
    p.add_argument("--epochs", type=int, default=None,
                   help="epochs per run (default 100; 1 with --quick); a run this sweep "
                        "finished with fewer is continued from its checkpoint to them")
    p.add_argument("--jobs", type=int, default=None,
                   help="runs at once (default: one per core)")
    p.add_argument("--actors", type=int, default=1, help="actors per run (default 1)")
    p.add_argument("--stacked", action="store_true",
                   help="the runs' learners as one process (hercs learner-stack), their "
                        "updates stacked: runs go in waves of --jobs, each a run of its own "
                        "(replay, actors, evaluator, checkpoints, metrics) but its learner "
                        "(docs/PERFORMANCE.md, the stacked learner)")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="SECTION.FIELD=VALUE", help="config override for every run")
    p.add_argument("--run-dir", default=None,
                   help="where runs go (default runs/sweep; a temp dir with --quick)")
    add_track_argument(p)
    p.add_argument("--out", default=None,
                   help="report folder (default RUN_DIR/report)")
    p.add_argument("--committed", default=None, metavar="DIR",
                   help="copy each finished run's small files here (to commit them); a cell "
                        "whose copy is here counts as done on any machine")
    p.add_argument("--report-only", action="store_true",
                   help="train nothing: report the runs finished so far")
    p.add_argument("--dry-run", action="store_true",
                   help="start nothing: print what each run would do now (skip, resume or "
                        "start, with its `hercs up` command); with --slurm, write the array "
                        "script and print it, submit nothing")
    p.add_argument("--quick", action="store_true",
                   help="CI mode: tiny runs in a temporary folder (seconds per run)")
    slurm = p.add_argument_group(
        "Slurm (docs/CLUSTER.md)", "--slurm submits one job array task per unfinished cell "
        "instead of training here; each task runs its cell with `hercs up` on one node, "
        "requeues itself before its time limit and resumes. The report is written by "
        "--report-only once the tasks are done.")
    slurm.add_argument("--slurm", action="store_true",
                       help="submit the grid as a Slurm job array (needs sbatch)")
    slurm.add_argument("--slurm-cpus", type=int, default=4, metavar="C",
                       help="CPUs per array task (default 4)")
    add_sbatch_arguments(slurm, prefix="slurm-", scope="each task")
    slurm.add_argument("--cell-index", type=int, default=None, help=argparse.SUPPRESS)
    return p


def tracking_overrides(track: Sequence[str], given: Sequence[str], run_root: Path) -> list[str]:
    """What `--track` adds to every cell: the trackers, and the sweep's folder name as their
    group (W&B's group, the MLflow experiment), unless `--set tracking.group=` names one."""
    if not track:
        return []
    grouped = any(item.partition("=")[0].strip() == "tracking.group" for item in given)
    return [*backends_override([], track),
            *([] if grouped else [f"tracking.group={run_root.name}"])]


def _fail(message: str) -> int:
    print(f"{PROG}: {message}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["report"]:
        return main_report(argv[1:])
    args = build_parser().parse_args(argv)
    try:  # where it writes, before any run starts
        for flag, folder in (("--run-dir", args.run_dir), ("--out", args.out),
                             ("--committed", args.committed)):
            if folder:
                check_output_folder(folder, flag=flag)
    except OutputPathError as exc:
        return _fail(str(exc))
    if args.seeds < 1:
        return _fail("--seeds must be at least 1")
    if args.first_seed < 1:
        return _fail(f"--first-seed {args.first_seed}: seeds start at 1")
    if args.jobs is not None and args.jobs < 1:
        return _fail("--jobs must be at least 1")
    tasks = args.tasks or (["reach"] if args.quick else ["push"])
    for task in tasks:
        try:
            task_spec(task, args.env_version)
        except ConfigError as exc:
            return _fail(f"--tasks {task}: {exc}")
    try:
        variants = [parse_variant(v) for v in args.variants]
        for _, items in variants:  # a bad field or value fails here, not in every run
            apply_overrides(HercsConfig(), list(items))
        apply_overrides(HercsConfig(), list(args.overrides))
    except ConfigError as exc:
        return _fail(str(exc))
    if len({name for name, _ in variants}) != len(variants):
        return _fail("two --variant arms have one name")
    if args.no_plain and not variants:
        return _fail("--no-plain leaves no arm: give a --variant too")
    arms = variants if args.no_plain else [("", ()), *variants]
    tasks = list(dict.fromkeys(tasks))
    methods = list(dict.fromkeys(args.methods))
    epochs = args.epochs or (1 if args.quick else 100)
    overrides = (list(args.overrides) + (list(QUICK_OVERRIDES) if args.quick else [])
                 + ([LEARNER_ELSEWHERE] if args.stacked else []))
    if args.stacked and (args.slurm or args.cell_index is not None):
        return _fail("--stacked runs a wave of --jobs runs here with one learner process; a "
                     "Slurm array runs each cell on its own node (drop one of them)")
    tmp = (tempfile.mkdtemp(prefix="hercs-sweep-")
           if args.quick and not args.run_dir and not args.dry_run else None)
    # --quick without --run-dir gets here only in a dry run, which makes no temporary folder
    default_root = (Path(tempfile.gettempdir()) / "hercs-sweep-NEW" if args.quick
                    else Path("runs") / "sweep")
    run_root = Path(args.run_dir or tmp or default_root).resolve()
    overrides = tracking_overrides(args.track or [], args.overrides, run_root) + overrides
    try:
        check_installed(apply_overrides(HercsConfig(), overrides).tracking)
    except ConfigError as exc:
        return _fail(str(exc))
    out_dir = Path(args.out) if args.out else run_root / "report"
    jobs = args.jobs or max(1, os.cpu_count() or 1)
    committed = Path(args.committed).resolve() if args.committed else None
    if args.weld_torquescale != 1.0 and (args.env_version != "v4"
                                         or not args.weld_torquescale > 0):
        return _fail(f"--weld-torquescale {args.weld_torquescale:g} needs --env-version v4 "
                     "and a value > 0")
    if args.energy_epsilon is not None and not args.energy_epsilon > 0:
        return _fail(f"--energy-epsilon {args.energy_epsilon:g} must be > 0")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    cells = plan_grid(tasks, methods, seeds, args.schedule, args.precision, args.env_version,
                      args.weld_torquescale, args.energy_epsilon, arms)
    problem = owned_override(args.overrides) or (
        None if args.energy_epsilon is not None else epsilon_changed(cells, run_root)) or (
        None if args.report_only else cannot_grow(cells, run_root, committed, epochs))
    if problem:
        return _fail(problem)
    names = [c.name for c in cells]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        return _fail(f"two cells would share a run folder ({', '.join(twice)}): rename a "
                     "--variant so that method-variant names stay apart")
    if not args.report_only:
        try:  # once here, not a failed `hercs up` per cell
            check_env(task_spec(tasks[0], args.env_version))
        except ConfigError as exc:
            return _fail(str(exc))
    command = f"{PROG} " + " ".join(argv)
    if args.dry_run and not args.slurm:
        print(f"sweep (dry run): {len(cells)} runs, {epochs} epochs each, {jobs} at a time, "
              f"in {run_root}" + (" (a new temporary folder)" if tmp is None and args.quick
                                  and not args.run_dir else ""))
        for line in dry_run_lines(cells, run_root=run_root, committed=committed, epochs=epochs,
                                  actors=args.actors, overrides=overrides):
            print(line)
        print("nothing was started (--dry-run)")
        return 0
    seeds_text = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {seeds[0]}..{seeds[-1]}"
    print(f"sweep: {len(cells)} runs ({', '.join(tasks)} × {', '.join(methods)} × "
          f"{len(arms)} arm{'s' if len(arms) != 1 else ''} × {seeds_text}), "
          f"{epochs} epochs each, {jobs} at a time, in {run_root}", flush=True)
    if args.cell_index is not None:
        if not 0 <= args.cell_index < len(cells):
            return _fail(f"--cell-index {args.cell_index}: the sweep has cells "
                         f"0..{len(cells) - 1}")
        return run_one_cell(lambda: run_grid(
            [cells[args.cell_index]], run_root=run_root, epochs=epochs, jobs=1,
            actors=args.actors, overrides=overrides, committed=committed, command=command,
            sweep=cells))
    if args.slurm and not args.report_only:
        run_root.mkdir(parents=True, exist_ok=True)
        write_manifest(run_root, cells, {}, command=command, epochs=epochs,
                       committed=committed)
        todo = [i for i, cell in enumerate(cells)
                if cell_state(cell, run_root, committed, epochs) not in ("done", "committed")]
        return submit_slurm(args, [c.name for c in cells], todo, tasks=tasks,
                            run_root=run_root, committed=committed, epochs=epochs,
                            overrides=overrides)
    failed = 0
    if not args.report_only:
        # SIGTERM (`kill`, a scheduler) stops the sweep as Ctrl-C does, and so does a SIGINT
        # that a non-interactive shell's `&` set to be ignored: each run stops in order and
        # is resumed by the next call, instead of going on without the sweep
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.default_int_handler)
        try:
            results = run_grid(cells, run_root=run_root, epochs=epochs, jobs=jobs,
                               actors=args.actors, overrides=overrides, committed=committed,
                               command=command, stacked=args.stacked)
        except KeyboardInterrupt:
            print(f"{PROG}: stopped; the same command resumes it", flush=True)
            return 130
        failed = sum(code != 0 for _, code in results)
    elif run_root.is_dir():
        write_manifest(run_root, cells, {}, command=command, epochs=epochs,
                       committed=committed)
    write_reports(cells, run_root, out_dir, command=command, committed=committed)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
