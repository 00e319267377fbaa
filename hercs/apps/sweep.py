"""`hercs sweep`: a grid of runs, tasks × methods × seeds × variants, each a full `hercs up`;
and `hercs sweep report`, its learning curves and its claims table.

    hercs sweep --tasks push --methods her her-cs --seeds 5 --epochs 50
    hercs sweep --tasks push --methods her-ebp-cs --seeds 3 --variant eps3:energy.epsilon=1e-3
    hercs sweep report runs/sweep

Each cell is one run, `hercs up --task T --method M --seed S --run T-M-sS` (`T-M-lockstep-sS`
with `--schedule lockstep`; `T-M-bf16-sS` with `--precision bf16`; `T-v1-M-sS` with
`--env-version v1`, the authors' Fetch*-v1 on mujoco-py after `make mujoco-py`; `T-M-NAME-sS`
for a `--variant NAME:FIELD=VALUE,...`, whose overrides only its runs get), under `--run-dir`
(default `runs/sweep`). A sweep is resumable: a run whose `bench_done.json` exists is skipped;
a run folder without it (the sweep was stopped while the run trained) is continued with
`hercs up --resume` from its last checkpoint (a folder with no saved config is moved aside to
`<run-dir>/_unfinished/`). Runs go `--jobs` at a time (default: one per core, since each run
is bound by its learner's one torch thread), each with its own router port. Cells run
seed-major, so that every arm has the same number of finished seeds as early as possible.
`<run-dir>/sweep.json` is the manifest: every cell, its state, and for a finished one the
commit and machine it was trained with.

`--committed DIR` holds the small files of every finished run (`config.yaml`, `metrics.csv`,
`bench_done.json`, and the first best policy of each cell), copied there when a run ends so
that they can be committed at once. A cell whose folder there has `bench_done.json` counts as
done on any machine (the sweep continues elsewhere), and the report reads a run from the run
directory or, when it is not there, from the committed folder.

When the sweep is done (or with `--report-only`; `hercs sweep report RUN_DIR` reads the
manifest), it writes per task `<task>.png` and `<task>.md` (`<task>-v1.*` for a v1 sweep):
our milestone table next to the authors' (docs/DESIGN.md §5) and, over the seeds of each arm,
the IQM of the success after the last epoch every run reached with its 95 % bootstrap
interval, and the probability that a run of one arm beats a run of another
(`hercs.apps.sweep_stats`), with the command, dates, commits and machines.

`--quick` is the CI mode: a tiny sweep (default Reach, 1 epoch of 2 cycles) into a temporary
folder, checking that the whole path — launch, resume, plot, report — still works.

`--slurm` submits one job array task per unfinished cell instead (`hercs.apps.sweep_slurm`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from hercs.apps import sweep_stats
from hercs.apps.plot_figures import plot_figure
from hercs.apps.plot_tables import tables
from hercs.apps.plots import (
    EPSILON_DEFAULT,
    Curve,
    aggregate,
    group,
    load_reference,
    load_run,
    method_key,
    method_label,
    method_rank,
    milestones,
)
from hercs.apps.provenance import cpu_info, git_commit, machine_identity
from hercs.apps.sweep_slurm import run_one_cell, submit_slurm
from hercs.config import PRECISIONS, SCHEDULES, HercsConfig, apply_overrides
from hercs.envs import check_env
from hercs.errors import ConfigError
from hercs.methods import METHODS
from hercs.rundir import CONFIG, METRICS, RunDir
from hercs.tasks import ENV_VERSIONS, TASKS, task_spec

PROG = "hercs sweep"
MANIFEST = "sweep.json"
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
    variant: str = ""
    """A `--variant`'s name ("" for none): its overrides are this cell's alone."""
    variant_overrides: tuple[str, ...] = ()

    @property
    def arm(self) -> str:
        """The cell without its seed: the runs a report aggregates over."""
        return self.name.rpartition("-s")[0]

    @property
    def name(self) -> str:
        """`T-M-sS`, the variants before the seed (`-lockstep`, `-bf16`) and a v1 env's
        version (or a v4 env's weld torquescale, `-ts4`) and EBP's ε other than the default
        (`-eps1e-3`) after the task: `push-v1-her-cs-lockstep-s2`."""
        variant = "".join(f"-{v}" for v, default in ((self.schedule, "async"),
                                                     (self.precision, "fp32"),
                                                     (self.variant, "")) if v != default)
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
              weld_torquescale: float = 1.0, energy_epsilon: float = EPSILON_DEFAULT,
              variants: Sequence[tuple[str, tuple[str, ...]]] = (("", ()),)
              ) -> list[GridRun]:
    """Every cell, seed-major: all arms of seed 1 before any of seed 2."""
    return [GridRun(t, m, s, schedule, precision, env_version, weld_torquescale, energy_epsilon,
                    name, tuple(overrides))
            for s in seeds for t in tasks for name, overrides in variants for m in methods]


VARIANT_NAME = re.compile(r"[a-z0-9][a-z0-9_.-]*")
RESERVED_VARIANTS = frozenset({"lockstep", "async", "bf16", "tf32", "fp32", "lag7", "cs",
                               "ebp", "ebp-cs", "her", "her-cs", "her-ebp", "her-ebp-cs"})
"""Names the runs' own naming and the plots' grouping already use."""


def parse_variant(text: str) -> tuple[str, tuple[str, ...]]:
    """`NAME:FIELD=VALUE[,FIELD=VALUE...]` → (NAME, ("FIELD=VALUE", ...)); ConfigError with
    what is wrong. The overrides are checked against the config when the sweep starts."""
    name, sep, rest = text.partition(":")
    items = tuple(item.strip() for item in rest.split(",") if item.strip())
    if not sep or not items or not all("=" in item for item in items):
        raise ConfigError(f"--variant {text!r}: give NAME:FIELD=VALUE[,FIELD=VALUE...], e.g. "
                          "lr5e-4:ddpg.lr_actor=5e-4,ddpg.lr_critic=5e-4")
    if name in RESERVED_VARIANTS or re.fullmatch(r"(v|ts|eps)[0-9].*|s[0-9]+", name):
        raise ConfigError(f"--variant {text!r}: its name {name!r} is one hercs gives runs "
                          "itself (an environment version, a schedule, a precision, a weld, "
                          "an energy floor or a seed): choose another")
    if not VARIANT_NAME.fullmatch(name):
        raise ConfigError(f"--variant {text!r}: its name {name!r} must be lower-case letters, "
                          "digits, '-', '_' or '.' (it becomes part of each run's name)")
    return name, items


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
    return RunDir(run_dir).config.is_file()


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
        for item in cell.variant_overrides:
            cmd += ["--set", item]
    for item in overrides:
        cmd += ["--set", item]
    return cmd


@dataclass
class _Running:
    cell: GridRun
    proc: subprocess.Popen[bytes]
    log: object
    started: float


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
    best = RunDir(run_dir).checkpoint("best")
    if best.is_file() and not any(publishes_policy(other, run_dir.name)
                                  for other in committed.iterdir() if other != target):
        RunDir(target).checkpoints.mkdir(exist_ok=True)
        shutil.copyfile(best, RunDir(target).checkpoint("best"))
    return target


def publishes_policy(committed_run: Path, run_name: str) -> bool:
    """Whether `committed_run` holds a best policy for the cell `run_name` names (the same
    name up to the seed: `push-v1-her-cs-s2` and `push-v1-her-cs-s1` are one cell)."""
    same_cell = committed_run.name.rpartition("-s")[0] == run_name.rpartition("-s")[0]
    return same_cell and (RunDir(committed_run).checkpoint("best")).is_file()


def write_manifest(run_root: Path, cells: Sequence[GridRun], state: dict[GridRun, str], *,
                   command: str, epochs: int, committed: Path | None) -> Path:
    """`<run_root>/sweep.json`: the sweep's command and every cell (its arm, settings and
    state; a finished one's record: commit, machine, wall time), rewritten as cells change,
    so that `hercs sweep report` and a person can see where the sweep stands."""
    entries = []
    for cell in cells:
        folder = finished_folder(cell, run_root, committed)
        record = json.loads((folder / DONE_FILE).read_text()) if folder is not None else None
        entries.append({
            "name": cell.name, "arm": cell.arm, "task": cell.task, "method": cell.method,
            "seed": cell.seed, "schedule": cell.schedule, "precision": cell.precision,
            "env_version": cell.env_version, "weld_torquescale": cell.weld_torquescale,
            "energy_epsilon": cell.energy_epsilon, "variant": cell.variant,
            "variant_overrides": list(cell.variant_overrides),
            "state": "done" if record is not None else state.get(cell, (
                "started, not finished" if (run_root / cell.name).is_dir() else "to do")),
            "folder": None if folder is None else str(folder),
            **({} if record is None else {
                "commit": record.get("commit"), "machine": record.get("machine"),
                "finished": record.get("finished"), "wall_s": record.get("wall_s")}),
        })
    path = run_root / MANIFEST
    # a temporary file of this writer's own (Slurm array tasks write at once), then an atomic
    # rename: a reader never sees half a manifest
    fd, tmp = tempfile.mkstemp(dir=run_root, prefix=f".{MANIFEST}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps({"command": command, "epochs": epochs, "cells": entries},
                               indent=2) + "\n")
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


def read_manifest(run_root: Path) -> tuple[list[GridRun], dict]:
    """The cells of the sweep in `run_root` and the manifest itself; ConfigError naming the
    folder when it holds no sweep."""
    path = run_root / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{run_root}: no sweep here ({path}: {exc}); give the --run-dir "
                          "of a `hercs sweep`") from exc
    cells = [GridRun(c["task"], c["method"], int(c["seed"]), c["schedule"], c["precision"],
                     c["env_version"], float(c["weld_torquescale"]), float(c["energy_epsilon"]),
                     c.get("variant", ""), tuple(c.get("variant_overrides", ())))
             for c in manifest["cells"]]
    return cells, manifest


def run_grid(cells: Sequence[GridRun], *, run_root: Path, epochs: int, jobs: int, actors: int,
             overrides: Sequence[str], committed: Path | None = None, command: str = "",
             sweep: Sequence[GridRun] | None = None) -> list[tuple[GridRun, int]]:
    """Train every unfinished cell, `jobs` at a time; returns (cell, exit code) per run started.

    A run that exits 0 gets `bench_done.json` (the env id it trained on, command, wall time of
    this invocation, epochs, commit, the CPU and boot id of the machine it finished on);
    one that fails or is interrupted is left in place and the next invocation continues it
    with `hercs up --resume` (its epochs already trained are kept). The manifest lists
    `sweep`'s cells (default: `cells`; a Slurm array task runs one cell of the sweep)."""
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
    state: dict[GridRun, str] = {}

    def manifest() -> None:  # of the whole sweep (`sweep`), not only the cells run here
        try:
            write_manifest(run_root, cells if sweep is None else sweep, state,
                           command=command, epochs=epochs, committed=committed)
        except OSError as exc:  # a manifest is a view of the runs; never stop them for it
            print(f"[manifest] not written: {exc}", flush=True)

    manifest()
    commit = git_commit()  # the code the runs train with (the report may be written later)
    machine = machine_identity()  # runs differ across CPUs even with one seed (DESIGN §10)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    try:
        while todo or running:
            while todo and len(running) < jobs:
                cell = todo.pop(0)
                # port 0: the router takes a free one itself (a port found free here could be
                # taken before `hercs up` binds it); router.json records it
                cmd = up_command(cell, epochs=epochs, run_root=run_root, port=0,
                                 actors=actors, overrides=overrides, resume=cell in resumed)
                log = open(run_root / LOG_DIR / f"{cell.name}.log", "wb")  # noqa: SIM115
                # its own session: a Ctrl-C at the terminal reaches only this driver, which
                # stops each run once (a second signal would skip `hercs up`'s orderly stop)
                proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                        start_new_session=True)
                running.append(_Running(cell, proc, log, time.monotonic()))
                state[cell] = "running"
                manifest()
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
                              "variant": r.cell.variant,
                              "variant_overrides": list(r.cell.variant_overrides),
                              "epochs": epochs,
                              "wall_s": round(wall, 1), "commit": commit,
                              "resumed": r.cell in resumed,
                              "command": " ".join(str(a) for a in r.proc.args[1:]),  # type: ignore[index]
                              "finished": datetime.now(UTC).isoformat(timespec="seconds"),
                              "machine": machine}
                    (run_root / r.cell.name / DONE_FILE).write_text(json.dumps(record, indent=2))
                    print(f"[done] {r.cell.name}: {wall / 60:.1f} min", flush=True)
                    if committed is not None:
                        copied = copy_small_files(run_root / r.cell.name, committed)
                        print(f"[done] {r.cell.name}: small files in {copied} (commit them)",
                              flush=True)
                else:
                    state[r.cell] = f"failed (exit {code}; resumed by the next call)"
                    print(f"[fail] {r.cell.name}: exit {code} after {wall:.0f} s; log "
                          f"{run_root / LOG_DIR / (r.cell.name + '.log')}", flush=True)
                manifest()
    except KeyboardInterrupt:
        print("interrupted: stopping the running runs (they will be resumed next time)",
              flush=True)
        for r in running:
            r.proc.terminate()
        for r in running:
            with contextlib.suppress(subprocess.TimeoutExpired):
                r.proc.wait(60)
            state[r.cell] = "stopped (resumed by the next call)"
        manifest()
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


def arm_key(cell: GridRun) -> str:
    """The plot's group key of a cell's arm (hercs.apps.plots.method_key; a `--variant`'s
    name after it): seeds of one arm are drawn as one curve."""
    key = method_key(cell.method, cell.schedule, cell.precision, cell.env_version,
                     torquescale=cell.weld_torquescale, energy_epsilon=cell.energy_epsilon)
    return f"{key}/{cell.variant}" if cell.variant else key


def arm_rows(curves: dict[str, list[Curve]], baseline: str | None,
             compare: Sequence[tuple[str, str]] = (), reps: int = sweep_stats.REPS
             ) -> tuple[int, list[str]]:
    """The claims-style table of one task: per arm the IQM of the success after the last
    epoch every run reached (10-epoch trailing mean) with its interval, and P(arm >
    `baseline`) and P(X > Y) for each of `compare` (arm labels or keys)."""
    epoch = min(int(c.epochs.max()) for cs in curves.values() for c in cs)
    final: dict[str, list[float]] = {}
    for key, cs in curves.items():
        at = [milestones(aggregate([c]), thresholds=(), at_epochs=(epoch,)).at[epoch]
              for c in cs]
        final[key] = [float(v) for v in at if v is not None]  # a run missing it is left out
    lines = [f"| arm | seeds | success after epoch {epoch}: IQM [95 % CI] | mean | "
             f"P(arm > {method_label(baseline) if baseline else '–'}) [95 % CI] |",
             "|---|---|---|---|---|"]
    for key in sorted(final, key=method_rank):
        v = final[key]
        iqm = sweep_stats.bootstrap(v, reps=reps).format()
        mean = sweep_stats.bootstrap(v, np.mean, reps=reps).format()
        if baseline is None or key == baseline or baseline not in final:
            versus = "–"
        else:
            versus = sweep_stats.improvement(v, final[baseline], reps=reps).format()
        lines.append(f"| {method_label(key)} | {len(v)} | {iqm} | {mean} | {versus} |")
    by_label = {method_label(k): k for k in final} | {k: k for k in final}
    extra = []
    for x, y in compare:
        if x in by_label and y in by_label:
            p = sweep_stats.improvement(final[by_label[x]], final[by_label[y]], reps=reps)
            extra.append(f"- P({x} > {y}) = {p.format()}")
    return epoch, lines + (["", *extra] if extra else [])


def write_reports(cells: Sequence[GridRun], run_root: Path, out_dir: Path, *, command: str,
                  reference_csv: Path | None = None, committed: Path | None = None,
                  compare: Sequence[tuple[str, str]] = (), reps: int = sweep_stats.REPS
                  ) -> list[Path]:
    """Per task: `<out>/<task>.png` and `<out>/<task>.md` from the finished runs
    (`<task>-v1.*` for runs on v1, so that a v1 sweep does not overwrite the v4 report)."""
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
        by_arm: dict[str, list[Curve]] = {}
        for c in done:
            by_arm.setdefault(arm_key(c), []).append(load_run(folders[c]))  # type: ignore[arg-type]
        title = by_arm[next(iter(by_arm))][0].task
        ours = {title: by_arm}
        heading = title if env_version == "v4" else f"{title}-{env_version}"
        figure = plot_figure(ours, out_dir / f"{stem}.png", reference)
        walls = [json.loads((folders[c] / DONE_FILE).read_text()) for c in done]  # type: ignore[operator]
        missing = [c.name for c in folders if c not in done]
        # the first arm the user named, when it has runs; else the first arm that has
        planned = arm_key(next(c for c in cells if (c.task, c.env_version) == (task, env_version)))
        baseline = planned if planned in by_arm else arm_key(done[0])
        epoch, stats = arm_rows(by_arm, baseline, compare, reps)
        lines = [
            f"# {heading}: {PROG} report", "",
            "Our runs (solid; band: 95 % CI of the seed mean) against the authors' published "
            "per-seed results (dashed; docs/DESIGN.md §5, `docs/reference/`).", "",
            f"![{heading}]({figure.name})", "",
            tables(ours, {title: reference.get(title, {})}).rstrip("\n"), "",
            "## Arms over seeds", "",
            f"Per run, the 10-epoch trailing mean of the test success after epoch {epoch} (the "
            "last every run reached); per arm its IQM and mean with 95 % percentile bootstrap "
            f"intervals over runs ({reps:,} resamples), and P(arm > {method_label(baseline)}), "
            "that a run of the arm beats one of it (ties half), with an interval from resampling "
            "each arm on its own (hercs/apps/sweep_stats.py). With few seeds an interval "
            "describes these seeds: an interval of P that excludes .5 is a lead, not a "
            "verdict.", "",
            *stats, "",
            "## How these were made", "",
            f"- command: `{command}`",
            f"- report written: {datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}",
            "- commits: " + ", ".join(sorted({str(w.get("commit", "unknown")) for w in walls})),
            "- machines: " + "; ".join(sorted({_machine_text(w) for w in walls})),
            f"- this machine: {machine_description()}",
            "- runs: " + ", ".join(
                f"{done_key(w)}{'/' + w['variant'] if w.get('variant') else ''} s{w['seed']} "
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


def _machine_text(record: dict) -> str:
    machine = record.get("machine") or {}
    if not machine:
        return "not recorded"
    return f"{machine.get('cpu', '?')}, boot {machine.get('boot_id', '?')}"


# ---------------------------------------------------------------------------------- CLI

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                                epilog="`hercs sweep report RUN_DIR` writes the report of a "
                                       "sweep from its manifest (--help there).",
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
    p.add_argument("--variant", dest="variants", action="append", default=[],
                   metavar="NAME:FIELD=VALUE[,FIELD=VALUE...]",
                   help="another arm: every task × method × seed again with these overrides, "
                        "runs named T-M-NAME-sS (repeat for more arms; the plain arm stays "
                        "unless --no-plain)")
    p.add_argument("--no-plain", action="store_true",
                   help="with --variant: only the variants' arms, not the plain one")
    p.add_argument("--epochs", type=int, default=None,
                   help="epochs per run (default 100; 1 with --quick)")
    p.add_argument("--jobs", type=int, default=None,
                   help="runs at once (default: one per core)")
    p.add_argument("--actors", type=int, default=1, help="actors per run (default 1)")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="SECTION.FIELD=VALUE", help="config override for every run")
    p.add_argument("--run-dir", default=None,
                   help="where runs go (default runs/sweep; a temp dir with --quick)")
    p.add_argument("--out", default=None,
                   help="report folder (default RUN_DIR/report)")
    p.add_argument("--committed", default=None, metavar="DIR",
                   help="copy each finished run's small files here (to commit them); a cell "
                        "whose copy is here counts as done on any machine")
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


def _fail(message: str) -> int:
    print(f"{PROG}: {message}", file=sys.stderr)
    return 2


def build_report_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=f"{PROG} report", description="Write a sweep's report from its manifest "
        "(RUN_DIR/sweep.json): per task the learning curves beside the authors', the "
        "milestone table, and per arm the IQM with its interval and P(improvement).")
    p.add_argument("run_dir", metavar="RUN_DIR", help="the sweep's --run-dir")
    p.add_argument("--out", default=None, help="report folder (default RUN_DIR/report)")
    p.add_argument("--committed", default=None, metavar="DIR",
                   help="where finished runs' small files were copied (read when a run's "
                        "folder is not in RUN_DIR)")
    p.add_argument("--compare", nargs=2, action="append", default=[], metavar=("X", "Y"),
                   help="also P(X > Y) between two arms, named as the table names them "
                        "(\"HER-CS lr5e-4\") or by key (her-cs/lr5e-4); repeatable")
    p.add_argument("--reps", type=int, default=sweep_stats.REPS,
                   help=f"bootstrap resamples (default {sweep_stats.REPS:,})")
    return p


def main_report(argv: Sequence[str]) -> int:
    args = build_report_parser().parse_args(argv)
    if args.reps < 100:
        return _fail(f"report --reps must be at least 100, got {args.reps}")
    run_root = Path(args.run_dir).resolve()
    try:
        cells, manifest = read_manifest(run_root)
    except ConfigError as exc:
        return _fail(str(exc))
    committed = Path(args.committed).resolve() if args.committed else None
    out_dir = Path(args.out) if args.out else run_root / "report"
    written = write_reports(cells, run_root, out_dir, command=manifest.get("command", ""),
                            committed=committed, compare=[tuple(c) for c in args.compare],
                            reps=args.reps)
    return 0 if written else 1


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["report"]:
        return main_report(argv[1:])
    args = build_parser().parse_args(argv)
    if args.seeds < 1:
        return _fail("--seeds must be at least 1")
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
    overrides = list(args.overrides) + (list(QUICK_OVERRIDES) if args.quick else [])
    tmp = tempfile.mkdtemp(prefix="hercs-sweep-") if args.quick and not args.run_dir else None
    run_root = Path(args.run_dir or tmp or Path("runs") / "sweep").resolve()
    out_dir = Path(args.out) if args.out else run_root / "report"
    jobs = args.jobs or max(1, os.cpu_count() or 1)
    committed = Path(args.committed).resolve() if args.committed else None
    if args.weld_torquescale != 1.0 and (args.env_version != "v4"
                                         or not args.weld_torquescale > 0):
        return _fail(f"--weld-torquescale {args.weld_torquescale:g} needs --env-version v4 "
                     "and a value > 0")
    if not args.energy_epsilon > 0:
        return _fail(f"--energy-epsilon {args.energy_epsilon:g} must be > 0")
    cells = plan_grid(tasks, methods, list(range(1, args.seeds + 1)), args.schedule,
                      args.precision, args.env_version, args.weld_torquescale,
                      args.energy_epsilon, arms)
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
    print(f"sweep: {len(cells)} runs ({', '.join(tasks)} × {', '.join(methods)} × "
          f"{len(arms)} arm{'s' if len(arms) != 1 else ''} × {args.seeds} seeds), {epochs} "
          f"epochs each, {jobs} at a time, in {run_root}", flush=True)
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
                if finished_folder(cell, run_root, committed) is None]
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
                               command=command)
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
