"""Sample efficiency against the paper: a grid of tasks × methods × seeds through `hercs up`.

    python -m bench.sample_efficiency --tasks push --methods her her-cs --seeds 3

Each cell of the grid is one full run, `hercs up --task T --method M --seed S --run T-M-sS`
(`T-M-lockstep-sS` with `--schedule lockstep`, the reference's schedule; `T-M-bf16-sS` with
`--precision bf16`, the learner's mixed precision; `T-v1-M-sS` with `--env-version v1`, the
authors' Fetch*-v1 on mujoco-py, which `make mujoco-py` installs), under `--run-dir`
(default `runs/sample_efficiency`). The grid is resumable: a run whose
`bench_done.json` exists is skipped; a run folder without it (the bench was stopped while the
run trained) is continued with `hercs up --resume` from its last checkpoint (a folder with no
saved config is moved aside to `<run-dir>/_unfinished/`). Runs go `--jobs` at a time (default: one
per core, since each run is bound by its learner's one torch thread), each with its own
router port. Cells run seed-major, so that every method has the same number of finished seeds
as early as possible.

Committed runs: `--committed` (default `docs/results/runs/`) holds the small files of every
finished run (`config.yaml`, `metrics.csv`, `bench_done.json`), copied there when a run ends so
that they can be committed at once. A cell whose folder there has `bench_done.json` counts as
done on any machine (the grid continues elsewhere), and the report reads a run from the run
directory or, when it is not there, from the committed folder.

When the grid is done (or with `--report-only`), `hercs plot --reference` draws one figure per
task and `docs/results/<task>.md` (`<task>-v1.md` for a v1 grid) puts our milestone table next
to the authors' (docs/DESIGN.md §5), with the figure, the command, date, commit and machine.
Each finished run's `bench_done.json` names the env id it trained on (`env_id`).

`--quick` is the CI mode: a tiny grid (default Reach, 1 epoch of 2 cycles) into a temporary
folder, checking that the whole path — launch, resume, plot, report — still works.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from bench.common import cpu_info, git_commit, machine_identity
from bench.grid_slurm import run_one_cell, submit_slurm
from hercs.apps.plot_figures import plot_figure
from hercs.apps.plot_tables import tables
from hercs.apps.plots import EPSILON_DEFAULT, group, load_reference, load_run, method_key
from hercs.config import PRECISIONS, SCHEDULES
from hercs.envs import check_env
from hercs.errors import ConfigError
from hercs.methods import METHODS
from hercs.rundir import BEST, CHECKPOINTS, CONFIG, METRICS
from hercs.tasks import ENV_VERSIONS, TASKS, task_spec

REPO = Path(__file__).resolve().parents[1]

DONE_FILE = "bench_done.json"
UNFINISHED_DIR = "_unfinished"
LOG_DIR = "_logs"
QUICK_OVERRIDES = ("training.cycles_per_epoch=2", "training.episodes_per_cycle=2",
                   "training.minibatches_per_cycle=2", "training.eval_episodes=2")
"""A run that exercises every part (rollouts, inserts, sampling, updates, eval) in seconds."""


@dataclass(frozen=True)
class GridRun:
    """One cell of the grid."""

    task: str
    method: str
    seed: int
    schedule: str = "async"
    precision: str = "fp32"
    env_version: str = "v4"
    weld_torquescale: float = 1.0
    energy_epsilon: float = EPSILON_DEFAULT

    @property
    def name(self) -> str:
        """`T-M-sS`, the variants before the seed (`-lockstep`, `-bf16`) and a v1 env's
        version (or a v4 env's weld torquescale, `-ts4`) and EBP's ε other than the default
        (`-eps1e-3`) after the task: `push-v1-her-cs-lockstep-s2`."""
        variant = "".join(f"-{v}" for v, default in ((self.schedule, "async"),
                                                     (self.precision, "fp32")) if v != default)
        env = "" if self.env_version == "v4" else f"-{self.env_version}"
        if self.weld_torquescale != 1.0:
            env += f"-ts{self.weld_torquescale:g}"
        if self.energy_epsilon != EPSILON_DEFAULT:
            mantissa, exponent = f"{self.energy_epsilon:e}".split("e")
            env += f"-eps{float(mantissa):g}e{int(exponent)}"
        return f"{self.task}{env}-{self.method}{variant}-s{self.seed}"

    @property
    def env_id(self) -> str:
        return task_spec(self.task, self.env_version).env_id


def plan_grid(tasks: Sequence[str], methods: Sequence[str], seeds: Sequence[int],
              schedule: str = "async", precision: str = "fp32", env_version: str = "v4",
              weld_torquescale: float = 1.0, energy_epsilon: float = EPSILON_DEFAULT
              ) -> list[GridRun]:
    """Every cell, seed-major: all methods of seed 1 before any of seed 2."""
    return [GridRun(t, m, s, schedule, precision, env_version, weld_torquescale, energy_epsilon)
            for s in seeds for t in tasks for m in methods]


def is_done(run_dir: Path) -> bool:
    return (run_dir / DONE_FILE).is_file()


def set_aside(run_dir: Path, root: Path) -> Path:
    """Move an unfinished run out of the way (kept, not deleted: its logs say why it stopped)."""
    dest_root = root / UNFINISHED_DIR
    dest_root.mkdir(parents=True, exist_ok=True)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    dest = dest_root / f"{run_dir.name}-{stamp}"
    run_dir.rename(dest)
    return dest


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def can_resume(run_dir: Path) -> bool:
    """An unfinished run `hercs up --resume` can continue: it saved its config."""
    return (run_dir / CONFIG).is_file()


def up_command(cell: GridRun, *, epochs: int, run_root: Path, port: int, actors: int,
               overrides: Sequence[str], resume: bool = False) -> list[str]:
    if resume:  # task, method, seed and name come from the run's saved config
        cmd = [sys.executable, "-m", "hercs.apps.cli", "up", "--resume", str(run_root / cell.name),
               "--epochs", str(epochs), "--actors", str(actors),
               "--listen", f"tcp/127.0.0.1:{port}"]
    else:
        cmd = [sys.executable, "-m", "hercs.apps.cli", "up", "--task", cell.task, "--method",
               cell.method, "--seed", str(cell.seed), "--epochs", str(epochs), "--run",
               cell.name, "--run-dir", str(run_root), "--actors", str(actors),
               "--listen", f"tcp/127.0.0.1:{port}", "--set", f"training.schedule={cell.schedule}",
               "--set", f"learner.precision={cell.precision}",
               "--set", f"task.env_version={cell.env_version}"]
        if cell.weld_torquescale != 1.0:
            cmd += ["--set", f"task.weld_torquescale={cell.weld_torquescale:g}"]
        if cell.energy_epsilon != EPSILON_DEFAULT:
            cmd += ["--set", f"energy.epsilon={cell.energy_epsilon!r}"]
    for item in overrides:
        cmd += ["--set", item]
    return cmd


@dataclass
class _Running:
    cell: GridRun
    proc: subprocess.Popen[bytes]
    log: object
    started: float


COMMITTED = REPO / "docs" / "results" / "runs"
SMALL_FILES = (CONFIG, METRICS, DONE_FILE)
"""What is committed of a finished run (the episode log and checkpoints stay where it ran)."""


def finished_folder(cell: GridRun, run_root: Path, committed: Path | None) -> Path | None:
    """Where a finished run's files are: its run folder, else its committed copy, else None."""
    for folder in (run_root / cell.name, None if committed is None else committed / cell.name):
        if folder is not None and is_done(folder):
            return folder
    return None


def copy_small_files(run_dir: Path, committed: Path) -> Path:
    """Copy a finished run's small files into `committed/<run>/` (for `git add`), and its best
    policy (`checkpoints/best.pt`: actor and normaliser, under 1 MB) where no committed run of
    the same task, method and variants publishes one yet (`publishes_policy`), so that
    `hercs eval docs/results/runs/<run>` works on a fresh clone."""
    target = committed / run_dir.name
    target.mkdir(parents=True, exist_ok=True)
    for name in SMALL_FILES:
        if (run_dir / name).is_file():
            shutil.copyfile(run_dir / name, target / name)
    best = run_dir / CHECKPOINTS / BEST
    if best.is_file() and not any(publishes_policy(other, run_dir.name)
                                  for other in committed.iterdir() if other != target):
        (target / CHECKPOINTS).mkdir(exist_ok=True)
        shutil.copyfile(best, target / CHECKPOINTS / BEST)
    return target


def publishes_policy(committed_run: Path, run_name: str) -> bool:
    """Whether `committed_run` holds a best policy for the cell `run_name` names (the same
    name up to the seed: `push-v1-her-cs-s2` and `push-v1-her-cs-s1` are one cell)."""
    same_cell = committed_run.name.rpartition("-s")[0] == run_name.rpartition("-s")[0]
    return same_cell and (committed_run / CHECKPOINTS / BEST).is_file()


def run_grid(cells: Sequence[GridRun], *, run_root: Path, epochs: int, jobs: int, actors: int,
             overrides: Sequence[str], committed: Path | None = None
             ) -> list[tuple[GridRun, int]]:
    """Train every unfinished cell, `jobs` at a time; returns (cell, exit code) per run started.

    A run that exits 0 gets `bench_done.json` (the env id it trained on, command, wall time of
    this invocation, epochs, commit, the CPU and boot id of the machine it finished on);
    one that fails or is interrupted is left in place and the next invocation continues it
    with `hercs up --resume` (its epochs already trained are kept)."""
    run_root.mkdir(parents=True, exist_ok=True)
    (run_root / LOG_DIR).mkdir(exist_ok=True)
    todo: list[GridRun] = []
    resumed: set[GridRun] = set()
    for cell in cells:
        run_dir = run_root / cell.name
        if is_done(run_dir):
            print(f"[skip] {cell.name}: finished earlier", flush=True)
            continue
        if committed is not None and is_done(committed / cell.name):
            print(f"[skip] {cell.name}: finished and committed ({committed / cell.name})",
                  flush=True)
            continue
        if can_resume(run_dir):
            print(f"[resume] {cell.name}: unfinished, continued where it stopped", flush=True)
            resumed.add(cell)
        elif run_dir.exists():
            print(f"[redo] {cell.name}: never started, moved to "
                  f"{set_aside(run_dir, run_root)}", flush=True)
        todo.append(cell)

    results: list[tuple[GridRun, int]] = []
    running: list[_Running] = []
    commit = git_commit()  # the code the runs train with (the report may be written later)
    machine = machine_identity()  # runs differ across CPUs even with one seed (DESIGN §10)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    try:
        while todo or running:
            while todo and len(running) < jobs:
                cell = todo.pop(0)
                cmd = up_command(cell, epochs=epochs, run_root=run_root, port=free_port(),
                                 actors=actors, overrides=overrides, resume=cell in resumed)
                log = open(run_root / LOG_DIR / f"{cell.name}.log", "wb")  # noqa: SIM115
                proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                        cwd=REPO)
                running.append(_Running(cell, proc, log, time.monotonic()))
                print(f"[start] {cell.name}: {' '.join(cmd[1:])}", flush=True)
            # Wait for any one child; polling at 1 s costs nothing next to runs of minutes.
            finished = [r for r in running if r.proc.poll() is not None]
            if not finished:
                time.sleep(1.0)
                continue
            for r in finished:
                running.remove(r)
                r.log.close()  # type: ignore[attr-defined]
                code = int(r.proc.returncode)
                wall = time.monotonic() - r.started
                results.append((r.cell, code))
                if code == 0:
                    record = {"task": r.cell.task, "method": r.cell.method, "seed": r.cell.seed,
                              "schedule": r.cell.schedule, "precision": r.cell.precision,
                              "env_version": r.cell.env_version, "env_id": r.cell.env_id,
                              "weld_torquescale": r.cell.weld_torquescale,
                              "energy_epsilon": r.cell.energy_epsilon,
                              "epochs": epochs,
                              "wall_s": round(wall, 1), "commit": commit,
                              "resumed": r.cell in resumed,
                              "command": " ".join(r.proc.args[1:]),  # type: ignore[index]
                              "finished": datetime.now(UTC).isoformat(timespec="seconds"),
                              "machine": machine}
                    (run_root / r.cell.name / DONE_FILE).write_text(json.dumps(record, indent=2))
                    print(f"[done] {r.cell.name}: {wall / 60:.1f} min", flush=True)
                    if committed is not None:
                        copied = copy_small_files(run_root / r.cell.name, committed)
                        print(f"[done] {r.cell.name}: small files in {copied} (commit them)",
                              flush=True)
                else:
                    print(f"[fail] {r.cell.name}: exit {code} after {wall:.0f} s; log "
                          f"{run_root / LOG_DIR / (r.cell.name + '.log')}", flush=True)
    except KeyboardInterrupt:
        print("interrupted: stopping the running runs (they will be resumed next time)",
              flush=True)
        for r in running:
            r.proc.terminate()
        for r in running:
            with contextlib.suppress(subprocess.TimeoutExpired):
                r.proc.wait(60)
        raise
    return results


# ------------------------------------------------------------------------------- report

def machine_description() -> str:
    model = cpu_info().get("model name", "")
    mem = ""
    with contextlib.suppress(OSError, ValueError, IndexError):
        kib = int(Path("/proc/meminfo").read_text().split("\n")[0].split()[1])
        mem = f", {kib / 2**20:.0f} GiB RAM"
    return (f"{os.cpu_count()} cores ({model or platform.processor() or 'unknown CPU'}){mem}, "
            f"{platform.system()} {platform.release()}, Python {platform.python_version()}, "
            "CPU only")


def done_key(record: dict) -> str:
    """The method key (hercs.apps.plots.method_key) of a `bench_done.json` record; older records
    have no schedule, precision or env version (async, fp32, v4)."""
    return method_key(record["method"], record.get("schedule", "async"),
                      record.get("precision", "fp32"), record.get("env_version", "v4"),
                      torquescale=float(record.get("weld_torquescale", 1.0)),
                      energy_epsilon=float(record.get("energy_epsilon", EPSILON_DEFAULT)))


def write_reports(cells: Sequence[GridRun], run_root: Path, out_dir: Path, *, command: str,
                  reference_csv: Path | None = None, committed: Path | None = None
                  ) -> list[Path]:
    """Per task: `<out>/<task>.png` and `<out>/<task>.md` from the finished runs
    (`<task>-v1.*` for runs on v1, so that a v1 grid does not overwrite the v4 report)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    ref_kwargs = {} if reference_csv is None else {"path": reference_csv}
    reference = group(load_reference(**ref_kwargs))
    written = []
    for task, env_version in dict.fromkeys((c.task, c.env_version) for c in cells):
        stem = task if env_version == "v4" else f"{task}-{env_version}"
        folders = {c: finished_folder(c, run_root, committed) for c in cells
                   if (c.task, c.env_version) == (task, env_version)}
        done = [c for c, folder in folders.items() if folder is not None]
        if not done:
            print(f"[report] {stem}: no finished run yet", flush=True)
            continue
        curves = [load_run(folders[c]) for c in done]  # type: ignore[arg-type]
        ours = group(curves)
        title = next(iter(ours))
        heading = title if env_version == "v4" else f"{title}-{env_version}"
        figure = plot_figure(ours, out_dir / f"{stem}.png", reference)
        walls = [json.loads((folders[c] / DONE_FILE).read_text()) for c in done]  # type: ignore[operator]
        missing = [c.name for c in folders if c not in done]
        lines = [
            f"# Sample efficiency: {heading}", "",
            "Our runs (solid, min–max band over seeds) against the authors' published "
            "per-seed results (dashed; docs/DESIGN.md §5, `docs/reference/`).", "",
            f"![{heading}]({figure.name})", "",
            tables(ours, {title: reference.get(title, {})}).rstrip("\n"), "",
            "## How these were made", "",
            f"- command: `{command}`",
            f"- date: {datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}",
            "- commit: " + ", ".join(sorted({str(w.get("commit", "unknown")) for w in walls})),
            f"- machine: {machine_description()}",
            "- runs: " + ", ".join(
                f"{done_key(w)} s{w['seed']} "
                f"({w['epochs']} epochs, {w['wall_s'] / 60:.0f} min)"
                for w in walls),
        ]
        if missing:
            lines.append("- not finished yet: " + ", ".join(missing))
        md = out_dir / f"{stem}.md"
        md.write_text("\n".join(lines) + "\n")
        written += [md, figure]
        print(f"[report] wrote {md} and {figure}", flush=True)
    return written


# ---------------------------------------------------------------------------------- CLI

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=None, metavar="TASK",
                   help=f"tasks: Fetch presets {sorted(TASKS)} or any task.name, e.g. "
                        "HandReach-v3 (default: push; reach with --quick)")
    p.add_argument("--methods", nargs="+", choices=list(METHODS), default=["her", "her-cs"])
    p.add_argument("--seeds", type=int, default=3, help="seeds 1..N (default 3)")
    p.add_argument("--schedule", choices=SCHEDULES, default="async",
                   help="training.schedule of every run (default async; lockstep runs are "
                        "named T-M-lockstep-sS)")
    p.add_argument("--precision", choices=PRECISIONS, default="fp32",
                   help="learner.precision of every run (default fp32; bf16 runs are named "
                        "T-M-bf16-sS)")
    p.add_argument("--env-version", choices=list(ENV_VERSIONS), default="v4",
                   help="task.env_version of every run (default v4; v1, the authors' Fetch*-v1 "
                        "on mujoco-py after `make mujoco-py`: runs named T-v1-M-sS)")
    p.add_argument("--energy-epsilon", type=float, default=EPSILON_DEFAULT,
                   help=f"energy.epsilon of every run (default {EPSILON_DEFAULT:g}; EBP's floor "
                        "added to every trajectory energy; 1e-3 gives v4's still episodes "
                        "v1's energy, docs/results/early_policy.md: runs named T-eps1e-3-M-sS)")
    p.add_argument("--weld-torquescale", type=float, default=1.0,
                   help="task.weld_torquescale of every run (v4 only; default 1, MuJoCo 3's; "
                        "4 tilts the gripper as v1 does, docs/results/env_diff.md: runs named "
                        "T-ts4-M-sS)")
    p.add_argument("--epochs", type=int, default=None,
                   help="epochs per run (default 100; 1 with --quick)")
    p.add_argument("--jobs", type=int, default=None,
                   help="runs at once (default: one per core)")
    p.add_argument("--actors", type=int, default=1, help="actors per run (default 1)")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="SECTION.FIELD=VALUE", help="config override for every run")
    p.add_argument("--run-dir", default=None,
                   help="where runs go (default runs/sample_efficiency; a temp dir with --quick)")
    p.add_argument("--out", default=None,
                   help="report folder (default docs/results; the run dir with --quick)")
    p.add_argument("--committed", default=None, metavar="DIR",
                   help="finished runs' small files, committed (default docs/results/runs; "
                        "none with --quick unless given)")
    p.add_argument("--report-only", action="store_true",
                   help="train nothing: report the runs finished so far")
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
    slurm.add_argument("--slurm-time", default="", metavar="LIMIT",
                       help="each task's time limit (sbatch --time); a longer run requeues")
    slurm.add_argument("--slurm-signal-before", type=int, default=300, metavar="S",
                       help="seconds before the limit at which a task stops and requeues "
                            "(default 300)")
    slurm.add_argument("--slurm-partition", default="", help="sbatch --partition")
    slurm.add_argument("--slurm-account", default="", help="sbatch --account")
    slurm.add_argument("--slurm-sbatch", action="append", default=[], metavar="OPTION",
                       help="one more sbatch option, e.g. --slurm-sbatch=--qos=high")
    slurm.add_argument("--dry-run", action="store_true",
                       help="with --slurm: write the array script and print it, submit nothing")
    slurm.add_argument("--cell-index", type=int, default=None, help=argparse.SUPPRESS)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.seeds < 1:
        print("sample_efficiency: --seeds must be at least 1", file=sys.stderr)
        return 2
    if args.jobs is not None and args.jobs < 1:
        print("sample_efficiency: --jobs must be at least 1", file=sys.stderr)
        return 2
    tasks = args.tasks or (["reach"] if args.quick else ["push"])
    for task in tasks:
        try:
            task_spec(task, args.env_version)
        except ConfigError as exc:
            print(f"sample_efficiency: --tasks {task}: {exc}", file=sys.stderr)
            return 2
    epochs = args.epochs or (1 if args.quick else 100)
    overrides = list(args.overrides) + (list(QUICK_OVERRIDES) if args.quick else [])
    tmp = tempfile.mkdtemp(prefix="hercs-se-") if args.quick and not args.run_dir else None
    run_root = Path(args.run_dir or tmp or REPO / "runs" / "sample_efficiency").resolve()
    out_dir = Path(args.out or (run_root / "results" if args.quick else REPO / "docs/results"))
    jobs = args.jobs or max(1, os.cpu_count() or 1)
    committed = (Path(args.committed).resolve() if args.committed
                 else None if args.quick else COMMITTED)
    if args.weld_torquescale != 1.0 and (args.env_version != "v4"
                                         or not args.weld_torquescale > 0):
        print(f"sample_efficiency: --weld-torquescale {args.weld_torquescale:g} needs "
              "--env-version v4 and a value > 0", file=sys.stderr)
        return 2
    if not args.energy_epsilon > 0:
        print(f"sample_efficiency: --energy-epsilon {args.energy_epsilon:g} must be > 0",
              file=sys.stderr)
        return 2
    cells = plan_grid(tasks, args.methods, list(range(1, args.seeds + 1)), args.schedule,
                      args.precision, args.env_version, args.weld_torquescale,
                      args.energy_epsilon)
    if not args.report_only:
        try:  # once here, not a failed `hercs up` per cell
            check_env(task_spec(tasks[0], args.env_version))
        except ConfigError as exc:
            print(f"sample_efficiency: {exc}", file=sys.stderr)
            return 2
    command = "python -m bench.sample_efficiency " + " ".join(
        a for a in (argv if argv is not None else sys.argv[1:]))
    print(f"grid: {len(cells)} runs ({', '.join(tasks)} × {', '.join(args.methods)} × "
          f"{args.seeds} seeds), {epochs} epochs each, {jobs} at a time, in {run_root}",
          flush=True)
    if args.cell_index is not None:
        if not 0 <= args.cell_index < len(cells):
            print(f"sample_efficiency: --cell-index {args.cell_index}: the grid has cells "
                  f"0..{len(cells) - 1}", file=sys.stderr)
            return 2
        return run_one_cell(lambda: run_grid(
            [cells[args.cell_index]], run_root=run_root, epochs=epochs, jobs=1,
            actors=args.actors, overrides=overrides, committed=committed))
    if args.slurm and not args.report_only:
        todo = [i for i, cell in enumerate(cells)
                if finished_folder(cell, run_root, committed) is None]
        return submit_slurm(args, [c.name for c in cells], todo, tasks=tasks,
                            run_root=run_root, committed=committed, epochs=epochs,
                            overrides=overrides)
    failed = 0
    if not args.report_only:
        results = run_grid(cells, run_root=run_root, epochs=epochs, jobs=jobs,
                           actors=args.actors, overrides=overrides, committed=committed)
        failed = sum(code != 0 for _, code in results)
    write_reports(cells, run_root, out_dir, command=command.strip(), committed=committed)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
