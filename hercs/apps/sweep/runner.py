"""`hercs sweep`'s runs: each cell a `hercs up` process, `--jobs` at a time, seed-major, with
its log, its starting commit and, once finished, its small files copied and recorded."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from hercs.apps.provenance import git_commit, machine_identity
from hercs.apps.sweep.cells import (
    DONE_FILE,
    GridRun,
    cannot_grow,
    cell_state,
    copy_small_files,
    done_record,
    finished_folder,
    set_aside,
    up_command,
    write_manifest,
)
from hercs.apps.sweep.learner_stack import WaveLearner
from hercs.apps.sweep.tally import SweepTally

LOG_DIR = "_logs"


@dataclass
class _Running:
    cell: GridRun
    proc: subprocess.Popen[bytes]
    log: object
    started: float


STARTED_SUFFIX = ".started"
"""Beside a cell's log: the commit its first life started from (a resumed run may finish with
another)."""


def started_commit(run_root: Path, name: str) -> str:
    """The commit cell `name` first started from ("" for a run started before this was
    recorded)."""
    path = run_root / LOG_DIR / f"{name}{STARTED_SUFFIX}"
    return path.read_text().strip() if path.is_file() else ""


def run_grid(cells: Sequence[GridRun], *, run_root: Path, epochs: int, jobs: int, actors: int,
             overrides: Sequence[str], committed: Path | None = None, command: str = "",
             sweep: Sequence[GridRun] | None = None,
             stacked: bool = False) -> list[tuple[GridRun, int]]:
    """Train every unfinished cell, `jobs` at a time; returns (cell, exit code) per run started.

    A run that exits 0 gets `bench_done.json` (the env id it trained on, command, wall time of
    this invocation, epochs, commit, the CPU and boot id of the machine it finished on);
    one that fails or is interrupted is left in place and the next invocation continues it
    with `hercs up --resume` (its epochs already trained are kept). A run finished with fewer
    than `epochs` is continued the same way to `epochs`; its new record adds the earlier
    one's wall time and says how many epochs it had (`grown_from_epochs`). The manifest lists
    `sweep`'s cells (default: `cells`; a Slurm array task runs one cell of the sweep).

    `stacked`: the cells run in waves of `jobs`, whose learners are one `hercs learner-stack`
    process (hercs.apps.sweep.learner_stack); `overrides` then hold its LEARNER_ELSEWHERE."""
    run_root.mkdir(parents=True, exist_ok=True)
    (run_root / LOG_DIR).mkdir(exist_ok=True)
    todo: list[GridRun] = []
    resumed: set[GridRun] = set()
    grown: dict[GridRun, dict] = {}  # a finished cell trained on: its earlier record
    for cell in cells:
        what = cell_state(cell, run_root, committed, epochs)
        if what == "stuck":  # main() refuses such a sweep first (cannot_grow)
            raise RuntimeError(cannot_grow([cell], run_root, committed, epochs))
        if what == "done":
            print(f"[skip] {cell.name}: finished earlier", flush=True)
            continue
        if what == "committed":
            assert committed is not None  # cell_state says "committed" only with a folder
            print(f"[skip] {cell.name}: finished and committed ({committed / cell.name})",
                  flush=True)
            continue
        if what == "resume":
            print(f"[resume] {cell.name}: unfinished, continued where it stopped", flush=True)
            resumed.add(cell)
        elif what == "grow":
            folder = finished_folder(cell, run_root, committed)
            grown[cell] = {} if folder is None else done_record(folder)
            print(f"[grow] {cell.name}: finished {grown[cell].get('epochs')} epochs, "
                  f"continued from its checkpoint to {epochs}", flush=True)
            resumed.add(cell)
        elif what == "redo":
            print(f"[redo] {cell.name}: never started, moved to "
                  f"{set_aside(run_root / cell.name, run_root)}", flush=True)
        todo.append(cell)

    results: list[tuple[GridRun, int]] = []
    running: list[_Running] = []
    state: dict[GridRun, str] = {}
    tally = SweepTally(total=len(cells), jobs=jobs, done=len(cells) - len(todo))

    def say_tally() -> None:
        now = time.monotonic()
        print(tally.line(left=len(todo), running_s=[now - r.started for r in running]),
              flush=True)

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
    wave = WaveLearner(run_root / LOG_DIR, env) if stacked else None
    try:
        while todo or running:
            wave_open = wave is None or not running  # a stacked sweep's next wave: all ended
            wave_since, wave_cells = time.time(), []
            while todo and len(running) < jobs and wave_open:
                cell = todo.pop(0)
                # port 0: the router takes a free one itself (a port found free here could be
                # taken before `hercs up` binds it); router.json records it
                cmd = up_command(cell, epochs=epochs, run_root=run_root, port=0,
                                 actors=actors, overrides=overrides, resume=cell in resumed)
                started = run_root / LOG_DIR / f"{cell.name}{STARTED_SUFFIX}"
                if not started.is_file():  # the commit of a cell's first life, kept through
                    started.write_text(commit + "\n")  # resumes for its bench_done.json
                log = open(run_root / LOG_DIR / f"{cell.name}.log", "wb")  # noqa: SIM115
                # its own session: a Ctrl-C at the terminal reaches only this driver, which
                # stops each run once (a second signal would skip `hercs up`'s orderly stop)
                proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                        start_new_session=True)
                running.append(_Running(cell, proc, log, time.monotonic()))
                state[cell] = "running"
                manifest()
                print(f"[start] {cell.name}: {' '.join(cmd[1:])}", flush=True)
                say_tally()
                wave_cells.append(run_root / cell.name)
            if wave is not None and wave_cells:
                wave.start_when_ready(wave_cells, wave_since, any_alive=lambda: any(
                    r.proc.poll() is None for r in running))
            if wave is not None:
                wave.watch([run_root / r.cell.name for r in running if r.proc.poll() is None])
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
                    earlier = grown.get(r.cell, {})
                    record = {"task": r.cell.task, "method": r.cell.method, "seed": r.cell.seed,
                              "schedule": r.cell.schedule, "precision": r.cell.precision,
                              "env_version": r.cell.env_version, "env_id": r.cell.env_id,
                              "weld_torquescale": r.cell.weld_torquescale,
                              "energy_epsilon": r.cell.epsilon,
                              "variant": r.cell.variant,
                              "variant_overrides": list(r.cell.variant_overrides),
                              "epochs": epochs,
                              # a grown run's: the invocations that trained it, together
                              "wall_s": round(wall + float(earlier.get("wall_s", 0.0)), 1),
                              "commit": commit,
                              "started_commit": started_commit(run_root, r.cell.name),
                              "resumed": r.cell in resumed,
                              **({"grown_from_epochs": int(earlier.get("epochs", 0))}
                                 if earlier else {}),
                              "command": " ".join(str(a) for a in r.proc.args[1:]),  # type: ignore[index]
                              "finished": datetime.now(UTC).isoformat(timespec="seconds"),
                              "machine": machine}
                    (run_root / r.cell.name / DONE_FILE).write_text(json.dumps(record, indent=2))
                    print(f"[done] {r.cell.name}: {wall / 60:.1f} min", flush=True)
                    tally.finished(wall, resumed=r.cell in resumed)
                    if committed is not None:
                        copied = copy_small_files(run_root / r.cell.name, committed)
                        print(f"[done] {r.cell.name}: small files in {copied} (commit them)",
                              flush=True)
                else:
                    state[r.cell] = f"failed (exit {code}; resumed by the next call)"
                    print(f"[fail] {r.cell.name}: exit {code} after {wall:.0f} s; log "
                          f"{run_root / LOG_DIR / (r.cell.name + '.log')}", flush=True)
                    tally.failed += 1
                manifest()
                if not todo:  # else the next [start] says it
                    say_tally()
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
    finally:
        if wave is not None:
            wave.stop()
    return results


# ---------------------------------------------------------------------------------- CLI
