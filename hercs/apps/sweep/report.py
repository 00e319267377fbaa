"""`hercs sweep report`: per task, a sweep's learning curves beside the authors', its milestone
table, and per arm the IQM of the final success with its 95 % interval and the probability
of improvement over another arm (`hercs.apps.sweep.stats`), with the command, commits and
machines."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import sys
from collections.abc import Sequence
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from hercs.apps.output_paths import OutputPathError, check_output_folder
from hercs.apps.plots.curves import (
    EPSILON_UNMARKED,
    Curve,
    aggregate,
    group,
    load_reference,
    load_run,
    method_key,
    method_rank,
    milestones,
)
from hercs.apps.plots.figures import plot_figure
from hercs.apps.plots.series import series_label
from hercs.apps.plots.tables import tables
from hercs.apps.provenance import cpu_info
from hercs.apps.sweep import stats as sweep_stats
from hercs.apps.sweep.cells import DONE_FILE, PROG, GridRun, finished_folder, read_manifest
from hercs.errors import ConfigError


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
    """The method key (hercs.apps.plots.curves.method_key) of a `bench_done.json` record;
    older records have no schedule, precision or env version (async, fp32, v4)."""
    return method_key(record["method"], record.get("schedule", "async"),
                      record.get("precision", "fp32"), record.get("env_version", "v4"),
                      torquescale=float(record.get("weld_torquescale", 1.0)),
                      energy_epsilon=float(record.get("energy_epsilon", EPSILON_UNMARKED)))


def arm_key(cell: GridRun) -> str:
    """The plot's group key of a cell's arm (hercs.apps.plots.curves.method_key; a `--variant`'s
    name after it): seeds of one arm are drawn as one curve."""
    key = method_key(cell.method, cell.schedule, cell.precision, cell.env_version,
                     torquescale=cell.weld_torquescale, energy_epsilon=cell.epsilon)
    return f"{key}/{cell.variant}" if cell.variant else key


def common_epoch(curves: dict[str, list[Curve]]) -> int:
    """The last epoch every run of every arm reached: where a report reads them all."""
    return min(int(c.epochs.max()) for cs in curves.values() for c in cs)


def cut_at(curves: dict[str, list[Curve]], epoch: int) -> dict[str, list[Curve]]:
    """The curves without their epochs past `epoch` (an arm of runs that went further is
    read where the others end)."""
    return {key: [replace(c, epochs=c.epochs[c.epochs <= epoch],
                          success=c.success[c.epochs <= epoch]) for c in cs]
            for key, cs in curves.items()}


def arm_rows(curves: dict[str, list[Curve]], baseline: str | None,
             compare: Sequence[tuple[str, str]] = (), reps: int = sweep_stats.REPS
             ) -> tuple[int, list[str]]:
    """The claims-style table of one task: per arm the IQM of the success after the last
    epoch every run reached (10-epoch trailing mean) with its interval, and P(arm >
    `baseline`) and P(X > Y) for each of `compare` (arm labels or keys; one without a
    finished run here is said to have none)."""
    epoch = common_epoch(curves)
    final: dict[str, list[float]] = {}
    for key, cs in curves.items():
        at = [milestones(aggregate([c]), thresholds=(), at_epochs=(epoch,)).at[epoch]
              for c in cs]
        final[key] = [float(v) for v in at if v is not None]  # a run missing it is left out
    lines = [f"| arm | seeds | success after epoch {epoch}: IQM [95 % CI] | mean | "
             f"P(arm > {series_label(baseline) if baseline else '–'}) [95 % CI] |",
             "|---|---|---|---|---|"]
    for key in sorted(final, key=method_rank):
        v = final[key]
        iqm = sweep_stats.bootstrap(v, reps=reps).format()
        mean = sweep_stats.bootstrap(v, np.mean, reps=reps).format()
        if baseline is None or key == baseline or baseline not in final:
            versus = "–"
        else:
            versus = sweep_stats.improvement(v, final[baseline], reps=reps).format()
        lines.append(f"| {series_label(key)} | {len(v)} | {iqm} | {mean} | {versus} |")
    by_label = {series_label(k): k for k in final} | {k: k for k in final}
    extra = []
    for x, y in compare:
        if x in by_label and y in by_label:
            p = sweep_stats.improvement(final[by_label[x]], final[by_label[y]], reps=reps)
            extra.append(f"- P({x} > {y}) = {p.format()}")
        else:
            absent = " and ".join(a for a in (x, y) if a not in by_label)
            extra.append(f"- P({x} > {y}): no finished run of {absent} on this task yet")
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
        loaded: dict[str, list[Curve]] = {}
        for c in done:
            loaded.setdefault(arm_key(c), []).append(load_run(folders[c]))  # type: ignore[arg-type]
        epoch = common_epoch(loaded)
        longer = sorted(Path(c.source).name for cs in loaded.values() for c in cs
                        if int(c.epochs.max()) > epoch)
        by_arm = cut_at(loaded, epoch)
        title = by_arm[next(iter(by_arm))][0].task
        ours = {title: by_arm}
        theirs = cut_at(reference.get(title, {}), epoch)
        heading = title if env_version == "v4" else f"{title}-{env_version}"
        figure = plot_figure(ours, out_dir / f"{stem}.png", {title: theirs})
        walls = [json.loads((folders[c] / DONE_FILE).read_text()) for c in done]  # type: ignore[operator]
        missing = [c.name for c in folders if c not in done]
        # the first arm the user named, when it has runs; else the first arm that has
        planned = arm_key(next(c for c in cells if (c.task, c.env_version) == (task, env_version)))
        baseline = planned if planned in by_arm else arm_key(done[0])
        _, stats = arm_rows(by_arm, baseline, compare, reps)
        against = ("against the authors' published per-seed results (dashed; docs/DESIGN.md "
                   "§5, `docs/reference/`)" if theirs else
                   f"(the authors published per-seed results for {', '.join(reference)} only: "
                   f"none for {title})")
        cut = (f"; runs that went further are cut there ({', '.join(longer)})" if longer
               else "")
        lines = [
            f"# {heading}: {PROG} report", "",
            f"Every arm is read at epoch {epoch}, the last epoch every finished run reached"
            f"{cut}.", "",
            f"Our runs (solid; band: 95 % CI of the seed mean) {against}.", "",
            f"![{heading}]({figure.name})", "",
            tables(ours, {title: theirs} if theirs else None).rstrip("\n"), "",
            "## Arms over seeds", "",
            f"Per run, the 10-epoch trailing mean of the test success after epoch {epoch} (the "
            "last every run reached); per arm its IQM and mean with 95 % percentile bootstrap "
            f"intervals over runs ({reps:,} resamples), and P(arm > {series_label(baseline)}), "
            "that a run of the arm beats one of it (ties half), with an interval from resampling "
            "each arm on its own (hercs/apps/sweep/stats.py). With few seeds an interval "
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
                        "(\"HER-CS, lr5e-4\") or by key (her-cs/lr5e-4); repeatable")
    p.add_argument("--reps", type=int, default=sweep_stats.REPS,
                   help=f"bootstrap resamples (default {sweep_stats.REPS:,})")
    return p


def main_report(argv: Sequence[str]) -> int:
    args = build_report_parser().parse_args(argv)
    if args.out:
        try:
            check_output_folder(args.out, flag="report --out")
        except OutputPathError as exc:
            return _fail(str(exc))
    if args.reps < 100:
        return _fail(f"report --reps must be at least 100, got {args.reps}")
    run_root = Path(args.run_dir).resolve()
    try:
        cells, manifest = read_manifest(run_root)
    except ConfigError as exc:
        return _fail(str(exc))
    keys = sorted({arm_key(c) for c in cells}, key=method_rank)
    for arm in (a for pair in args.compare for a in pair):
        if arm not in keys and arm not in map(series_label, keys):
            return _fail(f"--compare {arm}: no such arm in the sweep in {run_root}; its arms "
                         f"are {', '.join(map(series_label, keys))} (by key: "
                         f"{', '.join(keys)})")
    committed = Path(args.committed).resolve() if args.committed else None
    out_dir = Path(args.out) if args.out else run_root / "report"
    written = write_reports(cells, run_root, out_dir, command=manifest.get("command", ""),
                            committed=committed, compare=[tuple(c) for c in args.compare],
                            reps=args.reps)
    return 0 if written else 1
