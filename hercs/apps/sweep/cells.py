"""The cells of a `hercs sweep` and what a sweep keeps of them: `GridRun` (one run of the
grid: its name, its arm and its `hercs up` command), the plan and `--variant`s, a finished
run's `bench_done.json` and the small files copied for committing, and the manifest
`sweep.json` that says where the sweep stands."""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import shutil
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import yaml

from hercs.apps.plots.curves import marks_epsilon
from hercs.config.algorithm import default_energy_epsilon
from hercs.config.building import StrictBoolLoader
from hercs.errors import ConfigError
from hercs.rl.methods import METHODS
from hercs.rl.task_registry import task_spec
from hercs.run.rundir import CONFIG, DONE_RECORD, METRICS, RunDir

PROG = "hercs sweep"
MANIFEST = "sweep.json"
DONE_FILE = DONE_RECORD
UNFINISHED_DIR = "_unfinished"


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
    energy_epsilon: float | None = None
    """EBP's ε; None: the default of `env_version` (`epsilon`)."""
    variant: str = ""
    """A `--variant`'s name ("" for none): its overrides are this cell's alone."""
    variant_overrides: tuple[str, ...] = ()

    @property
    def arm(self) -> str:
        """The cell without its seed: the runs a report aggregates over."""
        return self.name.rpartition("-s")[0]

    @property
    def epsilon(self) -> float:
        """The ε the run uses: its variant's, else the one asked for, else the default of its
        environment (its variant's `task.env_version`, if it sets one)."""
        given: dict[str, str] = {}
        for item in self.variant_overrides:  # the last of a key wins, as in `hercs up`
            key, _, value = item.partition("=")
            given[key.strip()] = value.strip()
        env = given.get("task.env_version", self.env_version)
        if "energy.epsilon" in given:
            # read as `hercs up` reads an override's value (apply_overrides): YAML's null
            # unsets it; a value it would refuse names nothing here
            with contextlib.suppress(yaml.YAMLError, TypeError, ValueError):
                value = yaml.load(given["energy.epsilon"], Loader=StrictBoolLoader)
                return default_energy_epsilon(env) if value is None else float(value)
        if self.energy_epsilon is None:
            return default_energy_epsilon(env)
        return self.energy_epsilon

    @property
    def name(self) -> str:
        """`T-M-sS`, the variants before the seed (`-lockstep`, `-bf16`) and a v1 env's
        version (or a v4 env's weld torquescale, `-ts4`) and an EBP method's ε other than
        1e-6 (`-eps1e-3`, v4's default: plots.EPSILON_UNMARKED says why)
        after the task: `push-v1-her-cs-lockstep-s2`."""
        variant = "".join(f"-{v}" for v, default in ((self.schedule, "async"),
                                                     (self.precision, "fp32"),
                                                     (self.variant, "")) if v != default)
        env = "" if self.env_version == "v4" else f"-{self.env_version}"
        if self.weld_torquescale != 1.0:
            env += f"-ts{self.weld_torquescale:g}"
        if marks_epsilon(self.method, self.epsilon):
            mantissa, exponent = f"{self.epsilon:e}".split("e")
            env += f"-eps{float(mantissa):g}e{int(exponent)}"
        return f"{self.task}{env}-{self.method}{variant}-s{self.seed}"

    @property
    def env_id(self) -> str:
        return task_spec(self.task, self.env_version).env_id


def plan_grid(tasks: Sequence[str], methods: Sequence[str], seeds: Sequence[int],
              schedule: str = "async", precision: str = "fp32", env_version: str = "v4",
              weld_torquescale: float = 1.0, energy_epsilon: float | None = None,
              variants: Sequence[tuple[str, tuple[str, ...]]] = (("", ()),)
              ) -> list[GridRun]:
    """Every cell, seed-major: all arms of seed 1 before any of seed 2."""
    return [GridRun(t, m, s, schedule, precision, env_version, weld_torquescale, energy_epsilon,
                    name, tuple(overrides))
            for s in seeds for t in tasks for name, overrides in variants for m in methods]


VARIANT_NAME = re.compile(r"[a-z0-9][a-z0-9_.-]*")
RESERVED_VARIANTS = frozenset({"lockstep", "async", "bf16", "tf32", "fp32", "lag7"})
"""Names the runs' own naming and the plots' grouping already use, besides the methods'
(`reserved_variant`)."""


def reserved_variant(name: str) -> bool:
    """Whether a variant called `name` could be taken for a setting or a method: one of
    RESERVED_VARIANTS, a method's name, or the end of one after a '-' ("cs" would make
    `her` + "-cs" read as `her-cs`)."""
    tails = {m.split("-", cut)[-1] for m in METHODS for cut in range(1, m.count("-") + 1)}
    return name in RESERVED_VARIANTS or name in METHODS or name in tails


def parse_variant(text: str) -> tuple[str, tuple[str, ...]]:
    """`NAME:FIELD=VALUE[,FIELD=VALUE...]` → (NAME, ("FIELD=VALUE", ...)); ConfigError with
    what is wrong. The overrides are checked against the config when the sweep starts."""
    name, sep, rest = text.partition(":")
    items = tuple(item.strip() for item in rest.split(",") if item.strip())
    if not sep or not items or not all("=" in item for item in items):
        raise ConfigError(f"--variant {text!r}: give NAME:FIELD=VALUE[,FIELD=VALUE...], e.g. "
                          "lr5e-4:ddpg.lr_actor=5e-4,ddpg.lr_critic=5e-4")
    if reserved_variant(name) or re.fullmatch(r"(v|ts|eps)[0-9].*|s[0-9]+", name):
        raise ConfigError(f"--variant {text!r}: its name {name!r} is one hercs gives runs "
                          "itself (an environment version, a schedule, a precision, a weld, "
                          "an energy floor or a seed): choose another")
    if not VARIANT_NAME.fullmatch(name):
        raise ConfigError(f"--variant {text!r}: its name {name!r} must be lower-case letters, "
                          "digits, '-', '_' or '.' (it becomes part of each run's name)")
    return name, items


SWEEP_FLAGS = {"energy.epsilon": "--energy-epsilon", "task.env_version": "--env-version",
               "task.weld_torquescale": "--weld-torquescale",
               "training.schedule": "--schedule", "learner.precision": "--precision"}
"""Settings a cell's name says, so a sweep takes them by its own flags (or a `--variant`),
never by `--set`: a run must never train with one and be named after another."""


def owned_override(overrides: Sequence[str]) -> str | None:
    """Why `--set` may not carry one of these overrides, or None."""
    for item in overrides:
        key = item.partition("=")[0].strip()
        if key in SWEEP_FLAGS:
            return (f"--set {item}: a sweep names its runs after {key}; give it with "
                    f"{SWEEP_FLAGS[key]} (or in a --variant), not --set")
    return None


def epsilon_changed(cells: Sequence[GridRun], run_root: Path) -> str | None:
    """Why the sweep in `run_root` must not go on with `cells`, or None: its manifest has
    cells of the same task, method, seed and arm under another name because they were
    planned with another ε (a sweep begun before v4's default ε became 1e-3, run again
    without --energy-epsilon): its runs would be passed over, not continued."""
    try:
        old, _ = read_manifest(run_root)
    except ConfigError:
        return None
    names = {c.name for c in cells}
    same = {(c.task, c.method, c.seed, c.env_version, c.variant) for c in cells}
    moved = [c for c in old if c.name not in names and c.energy_epsilon is not None
             and (c.task, c.method, c.seed, c.env_version, c.variant) in same]
    if not moved:
        return None
    return (f"{run_root} holds this sweep's {', '.join(c.name for c in moved[:3])}"
            f"{' …' if len(moved) > 3 else ''} planned with energy.epsilon "
            f"{moved[0].energy_epsilon:g}, which the cells would now be named apart from (v4's "
            f"default ε is 1e-3): give --energy-epsilon "
            f"{moved[0].energy_epsilon:g} to go on with them, or another --run-dir")


def is_done(run_dir: Path) -> bool:
    return (run_dir / DONE_FILE).is_file()


def done_record(run_dir: Path) -> dict:
    """A finished run's `bench_done.json` ({} where it is missing or unreadable)."""
    try:
        record = json.loads((run_dir / DONE_FILE).read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def done_epochs(run_dir: Path) -> int:
    """The epochs a finished run trained, as its `bench_done.json` records them."""
    return int(done_record(run_dir).get("epochs", 0))


def set_aside(run_dir: Path, root: Path) -> Path:
    """Move an unfinished run out of the way (kept, not deleted: its logs say why it stopped)."""
    dest_root = root / UNFINISHED_DIR
    dest_root.mkdir(parents=True, exist_ok=True)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    dest = dest_root / f"{run_dir.name}-{stamp}"
    run_dir.rename(dest)
    return dest


def can_resume(run_dir: Path) -> bool:
    """An unfinished run `hercs up --resume` can continue: it saved its config."""
    return RunDir(run_dir).config.is_file()


def cell_state(cell: GridRun, run_root: Path, committed: Path | None, epochs: int) -> str:
    """What a sweep of `epochs` epochs does with `cell` now: "done" (finished them in
    `run_root`), "committed" (finished them, its copy in `committed`), "grow" (finished fewer
    in `run_root`: continued from its checkpoint to `epochs`), "stuck" (finished fewer, but
    with no checkpoint here to continue from: `cannot_grow` says why), "resume" (unfinished,
    continued), "redo" (a folder that never saved its config, set aside first) or "start"."""
    run_dir = run_root / cell.name
    copy = None if committed is None else committed / cell.name
    if is_done(run_dir) and done_epochs(run_dir) >= epochs:
        return "done"
    if copy is not None and is_done(copy) and done_epochs(copy) >= epochs:
        return "committed"
    if is_done(run_dir) or (copy is not None and is_done(copy)):
        return "grow" if RunDir(run_dir).checkpoint("latest").is_file() else "stuck"
    if can_resume(run_dir):
        return "resume"
    return "redo" if run_dir.exists() else "start"


def cannot_grow(cells: Sequence[GridRun], run_root: Path, committed: Path | None,
                epochs: int) -> str | None:
    """Why this sweep cannot train its cells to `epochs`, or None: a cell finished fewer
    epochs where no learner checkpoint is kept to continue from (a committed copy keeps
    none), and training it again from epoch 1 would not be the same run."""
    stuck = [c for c in cells if cell_state(c, run_root, committed, epochs) == "stuck"]
    if not stuck:
        return None
    folders = [finished_folder(c, run_root, committed) for c in stuck]
    trained = [done_epochs(f) for f in folders if f is not None]
    listed = ", ".join(f"{c.name} ({n} epochs, in {f})"
                       for c, n, f in zip(stuck[:3], trained, folders, strict=False))
    return (f"--epochs {epochs}: {listed}{' …' if len(stuck) > 3 else ''} finished fewer "
            "epochs and keeps no learner checkpoint here (checkpoints/learner.pt) to continue "
            "from, so it cannot be grown; run the sweep where its run folder is, or give "
            f"--epochs {min(trained, default=epochs)}")


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
        if cell.energy_epsilon is not None:
            cmd += ["--set", f"energy.epsilon={cell.energy_epsilon!r}"]
        for item in cell.variant_overrides:
            cmd += ["--set", item]
    for item in overrides:
        cmd += ["--set", item]
    return cmd


def dry_run_lines(cells: Sequence[GridRun], *, run_root: Path, committed: Path | None,
                  epochs: int, actors: int, overrides: Sequence[str]) -> list[str]:
    """What `hercs sweep --dry-run` prints: a line per cell, what the sweep would do with it
    now and the `hercs up` it would run (the router's port chosen at start: 0)."""
    lines = []
    for cell in cells:
        what = cell_state(cell, run_root, committed, epochs)
        if what in ("done", "committed"):
            folder = finished_folder(cell, run_root, committed)
            lines.append(f"[skip] {cell.name}: finished ({folder})")
            continue
        cmd = up_command(cell, epochs=epochs, run_root=run_root, port=0, actors=actors,
                         overrides=overrides, resume=what in ("resume", "grow"))
        shown = shlex.join(["hercs", *cmd[3:]])  # not `python -m hercs.apps.cli`
        if what == "redo":
            lines.append(f"[redo] {cell.name}: its folder never saved a config; it would be "
                         f"set aside, then: {shown}")
        elif what == "grow":
            folder = finished_folder(cell, run_root, committed)
            trained = 0 if folder is None else done_epochs(folder)
            lines.append(f"[grow] {cell.name}: finished {trained} epochs; continued from its "
                         f"checkpoint: {shown}")
        else:
            lines.append(f"[{what}] {cell.name}: {shown}")
    return lines


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
        record = done_record(folder) if folder is not None else None
        trained = None if record is None else int(record.get("epochs", 0))
        if trained is not None and trained >= epochs:
            now = "done"
        elif cell in state:
            now = state[cell]
        elif trained is not None:  # to be grown to `epochs`
            now = f"finished {trained} epochs of {epochs}"
        else:
            now = "started, not finished" if (run_root / cell.name).is_dir() else "to do"
        entries.append({
            "name": cell.name, "arm": cell.arm, "task": cell.task, "method": cell.method,
            "seed": cell.seed, "schedule": cell.schedule, "precision": cell.precision,
            "env_version": cell.env_version, "weld_torquescale": cell.weld_torquescale,
            # as asked (null: the environment's default) and as the run uses it
            "energy_epsilon": cell.energy_epsilon, "epsilon_used": cell.epsilon,
            "variant": cell.variant,
            "variant_overrides": list(cell.variant_overrides),
            "state": now,
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
                     c["env_version"], float(c["weld_torquescale"]),
                     None if c.get("energy_epsilon") is None else float(c["energy_epsilon"]),
                     c.get("variant", ""), tuple(c.get("variant_overrides", ())))
             for c in manifest["cells"]]
    return cells, manifest
