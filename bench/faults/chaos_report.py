"""The report of the chaos soaks and their fault-free seeds (docs/results/chaos.{md,json}),
from each run's record (bench/faults/chaos_record.py): per soak its injections and what
followed them, its run's measures, its success curve against the fault-free envelope
(bench/faults/chaos_envelope.py) and its environment steps per update.
"""

from __future__ import annotations

import csv
import json
import os
import platform
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import git_commit
from bench.faults.chaos_envelope import (
    EnvelopeCheck,
    check,
    config_differences,
    leave_one_out,
    smoothed,
    success_curve,
)
from bench.faults.chaos_record import RECORD
from hercs.run.rundir import RunDir

VALIDATION = "chaos_validation.md"
"""Runs of the machinery (written by hand): linked from the report when beside it."""


# ------------------------------------------------------------------------------ report

def _s(value: float | None) -> str:
    return "–" if value is None else f"{value:g} s"


def _load(folder: Path) -> dict[str, Any] | None:
    path = folder / RECORD
    return json.loads(path.read_text()) if path.is_file() else None


LEARNED = 0.5
"""A fault-free seed whose smoothed success never reaches this has not taken off: the report
says that its envelope cannot judge learning then."""


def _folders(roots: Sequence[Path | None], pattern: str) -> dict[str, Path]:
    """Run folders matching `pattern` under each root (an earlier root wins a name); the
    actors' logs and the launcher's output beside them (`<run>.net-1.0.log`, `<run>.out`)
    match the pattern too and are not runs."""
    found: dict[str, Path] = {}
    for root in roots:
        if root is not None and root.is_dir():
            for folder in sorted(root.glob(pattern)):
                if folder.is_dir():
                    found.setdefault(folder.name, folder)
    return found


def _envelope_verdict(result: EnvelopeCheck, calibration: dict[str, EnvelopeCheck]) -> bool:
    """Inside, or outside at no more epochs than some fault-free seed against the others."""
    if result.inside:
        return True
    return bool(calibration) and len(result.outside) <= max(
        len(c.outside) for c in calibration.values())


def report(chaos: list[dict[str, Any]], baselines: dict[str, list[float]],
           free_records: list[dict[str, Any]], *, command: str, window: int,
           config_notes: list[str], full_commands: list[str],
           validation: str = "") -> tuple[str, bool]:
    """The markdown of the soaks in `chaos` against the fault-free curves `baselines` (and a
    link to the `validation` runs' page, if any); and whether every soak kept every
    promise."""
    quick = any(r["quick"] for r in chaos)
    loads = [v for r in chaos + free_records for v in (r["result"]["load_before"],
                                                       r["result"]["load_after"])]
    load = f"; 1-min load average {min(loads):.1f}–{max(loads):.1f}" if loads else ""
    lines = [
        "# Chaos soak: kills and partitions through a whole run", "",
        f"`{command}` — {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, commit {git_commit()}, "
        f"{platform.node()} ({os.cpu_count()} cores{load})"
        f"{' — QUICK MODE (CI size: a check of the machinery, not the soak)' if quick else ''}.",
        "",
        "Each run is `hercs up --actors 0` on this host with mutual TLS and its actors each in "
        "a network namespace behind a veth link (bench/faults/chaos.py, bench/faults/netns.py). "
        "A soak's schedule (bench/faults/chaos_plan.py, drawn from its chaos seed) SIGKILLs a "
        "service (the "
        "launcher restarts it) or a remote actor (the bench restarts it after 1 s, as its "
        "host's supervisor would) and cuts one actor's link both ways (iptables DROP); a "
        "fault-free seed is the same run with nothing injected. Acked = distinct (actor, "
        "seq) the actors logged as acked (every incarnation, killed ones included); lost = "
        "those missing from the episode log; stored twice = log records − distinct (actor, "
        "seq). Lag: median of the epochs' p50 / largest p95 (cycles). Times are on the run's "
        "clock (seconds since the launch).", "",
        "| run | injected | exit up / actors | epochs | acked | lost | stored twice | retries "
        "| dup acks | lag p50 / p95 | inserts/s | longest insert gap | epoch median / max | "
        "final success (mean of last 3) | envelope | wall | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    calibration = leave_one_out(baselines, window=window)
    all_ok = True
    checks: dict[str, EnvelopeCheck] = {}
    for r in [*chaos, *free_records]:
        res = r["result"]
        curve = r["success"]
        tail = [v for v in curve[-3:] if v == v]
        if r["chaos_seed"] is None:
            envelope = "(fault-free seed)"
        elif baselines:
            checks[r["name"]] = c = check(curve, list(baselines.values()), window=window)
            inside = _envelope_verdict(c, calibration)
            envelope = f"{'ok' if inside else 'OUTSIDE'}: {c.describe()}"
            all_ok &= inside
        else:
            envelope = "not checked: no fault-free seeds"
        all_ok &= bool(r["ok"])
        epochs_ok = res["epochs_recorded"] == list(range(1, res["epochs_expected"] + 1))
        lines.append(
            f"| {r['name']} | {res['injected']} | {'/'.join(map(str, r['up_exits']))} / "
            f"{','.join(map(str, res['actor_exits']))} | {len(res['epochs_recorded'])} "
            f"({res['epochs_expected']}){'' if epochs_ok else ' ✗'} | {res['acked']} | "
            f"{res['lost']} | {res['stored_twice']} | {res['retries']} | "
            f"{res['duplicate_acks']} | {res['lag_p50']} / {res['lag_p95']} | "
            f"{res['inserts_per_s']} | {_s(res['longest_insert_gap_s'])} | "
            f"{_s(res['median_epoch_s'])} / {_s(res['max_epoch_s'])} | "
            f"{(curve or [float('nan')])[-1]:.2f} ({sum(tail) / max(len(tail), 1):.2f}) | "
            f"{envelope} | {res['wall_s']} s | {'ok' if r['ok'] else 'FAILED'} |")
    for r in [*chaos, *free_records]:
        lines += [f"\n- {r['name']}: {n}" for n in r["result"]["notes"]]
    for r in chaos:
        lines += _injections(r)
    if baselines:
        lines += _curves(chaos, baselines, checks, calibration, window, config_notes)
    if validation:
        lines += ["", "The machinery's validation runs (the quick mode, a 10-epoch FetchReach "
                  "soak at four times the pace with the launcher among the targets, a bench "
                  f"stopped and resumed): [{validation}]({validation})."]
    if not any(not r["quick"] for r in chaos):
        lines += ["", "## Full soak: not yet run", "",
                  "The issue's soak (FetchPush, HER-EBP-CS, 20 epochs, 2 remote actors over "
                  "TLS, chaos seed 1) and its fault-free seeds (the same run with nothing "
                  "injected, seeds 1–3) are four runs of 20 epochs: about 10 min each on 2 "
                  "idle cores, 20–40 min beside other runs. They are run as root from the "
                  "repository root by the commands below. Each run lives in runs/chaos/ and, "
                  "once finished, is copied to docs/results/runs/ (`config.yaml`, "
                  "`metrics.csv`, `chaos.json`; commit them); a command stopped midway "
                  "continues where it stopped when given again, and a committed run is "
                  "skipped. The last command writes this file and chaos.json anew from the "
                  "committed runs.", "", "```", *full_commands, "```"]
    return "\n".join(lines) + "\n", all_ok


def _injections(r: dict[str, Any]) -> list[str]:
    plan = r["plan"] or {}

    def span(key: str) -> str:
        low, high = plan.get(key, (0, 0))
        return f"{low:g} s" if low == high else f"{low:g}–{high:g} s"

    lines = ["", f"## What was injected: {r['name']}", "",
             f"Chaos seed {r['chaos_seed']}: a kill every {span('kill_gap_s')} among "
             f"{', '.join(plan.get('targets', []))}; a cut of {span('cut_s')}, "
             f"{span('cut_gap_s')} after the launch or the previous heal "
             f"({r['schedule_drawn']} events "
             "drawn up to "
             f"{plan.get('horizon_s', 0) / 3600:g} h; {len(r['schedule'])} fell within the "
             "run). Back = the target running again: a service's \"started … again\" line, "
             "a launcher's \"resuming run\", an actor's session seen by the router "
             "(\"remote actor … joined\"; after a kill, its new incarnation's, started 1 s "
             "after the kill; after a cut, – if the session outlived the cut); next insert = "
             "of the killed actor's new incarnation, of the cut actor, of any actor after a "
             "service's kill; all from the kill or the heal.", "",
             "| at (planned) | injection | pid | back after | next insert after | next epoch "
             "after | outcome |", "|---|---|---|---|---|---|---|"]
    for i in r["injections"]:
        if i["kind"] == "cut":
            healed = i.get("healed_at_s")
            what = (f"cut {i['target']} both ways {i['duration_s']:g} s (healed at "
                    f"{'–' if healed is None else f'{healed:g}'} s)")
        elif i["kind"] == "kill":
            what = f"SIGKILL {i['target']}"
        else:
            what = i["kind"]
        planned = f" ({i['planned_at_s']:g})" if "planned_at_s" in i else ""
        lines.append(f"| {i['at_s']:g} s{planned} | {what} | {i.get('pid') or '–'} | "
                     f"{_s(i.get('back_s'))} | {_s(i.get('next_insert_s'))} | "
                     f"{_s(i.get('next_epoch_s'))} | {i['outcome']} |")
    return lines


def _curves(chaos: list[dict[str, Any]], baselines: dict[str, list[float]],
            checks: dict[str, EnvelopeCheck], calibration: dict[str, EnvelopeCheck],
            window: int, config_notes: list[str]) -> list[str]:
    names = list(baselines)
    lines = ["", "## Success against the fault-free seeds", "",
             f"Success rate per epoch (the evaluator's greedy episodes) of each soak and of "
             f"the fault-free seeds {', '.join(names)}; the envelope is [min, max] of the "
             f"fault-free seeds after a trailing mean over {window} epochs "
             "(bench/faults/chaos_envelope.py explains why smoothed, and why an envelope of n "
             "seeds "
             "holds a fresh fault-free seed at one epoch only with probability "
             "(n − 1)/(n + 1)).", ""]
    if calibration:
        lines += ["Calibration, each fault-free seed against the envelope of the others: " +
                  "; ".join(f"{n}: {c.describe()}" for n, c in calibration.items()) +
                  ". A soak passes when it is inside, or outside at no more epochs than a "
                  "fault-free seed is.", ""]
    best = max((max(smoothed(c, window)) for c in baselines.values() if c), default=None)
    if best is not None and best < LEARNED:
        lines += [f"What this check can tell: no fault-free seed got past a smoothed success of "
                  f"{best:.2f} (< {LEARNED}) in these epochs: the runs are still before the "
                  "take-off, so the envelope shows that the faults did not break the run's "
                  "early course, but it cannot tell a soak that goes on to learn from one that "
                  "does not.", ""]
    lines += [f"| epoch | {' | '.join(r['name'] + ' raw (smoothed)' for r in chaos)} | "
              f"envelope (smoothed) | {' | '.join(n + ' raw' for n in names)} |",
              "|---|" + "---|" * (len(chaos) + 1 + len(names))]
    smooth = {n: smoothed(c, window) for n, c in baselines.items()}
    length = max([len(c) for c in baselines.values()] + [len(r["success"]) for r in chaos])
    for e in range(length):
        cells = []
        for r in chaos:
            curve = r["success"]
            cells.append(f"{curve[e]:.2f} ({smoothed(curve, window)[e]:.2f})"
                         if e < len(curve) else "–")
        values = [s[e] for s in smooth.values() if e < len(s)]
        envelope = f"{min(values):.2f}–{max(values):.2f}" if values else "–"
        base = [f"{c[e]:.2f}" if e < len(c) else "–" for c in baselines.values()]
        lines.append(f"| {e + 1} | {' | '.join(cells)} | {envelope} | {' | '.join(base)} |")
    for name, c in checks.items():
        lines.append(f"\n- {name}: {c.describe()}.")
    lines += [f"\n- {n}" for n in config_notes]
    return lines


STEPS_TOLERANCE = 0.05
"""A soak's epoch whose env steps per update differ from the fault-free seeds' median by more
than this share changed the experiment, not only its wall time."""


def steps_per_update(run_dir: Path) -> list[float]:
    """Each epoch's env steps per DDPG update, from `metrics.csv` (NaN for an epoch without
    updates)."""
    path = RunDir(run_dir).metrics
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        rows = [(int(r["env_steps"]), int(r["updates"])) for r in csv.DictReader(f)]
    out, before = [], (0, 0)
    for steps, updates in rows:
        done = updates - before[1]
        out.append((steps - before[0]) / done if done > 0 else float("nan"))
        before = (steps, updates)
    return out


def _steps_section(runs: dict[str, list[float]], free: dict[str, list[float]]) -> list[str]:
    """The per-epoch env steps per update of each soak against the fault-free seeds' median."""
    if not runs or not free:
        return []
    width = max(len(v) for v in [*runs.values(), *free.values()])
    reference = [float(np.nanmedian([v[i] for v in free.values() if i < len(v)]))
                 for i in range(width)]
    lines = ["", "## Env steps per update, by epoch", "",
             "A fault should change only a run's wall time: each epoch takes the env steps per "
             "DDPG update of the fault-free seeds (their median per epoch; epoch 1 includes "
             "the buffer's warm-up). Worst = the epoch (from 2) furthest from it, as a share; "
             f"✗ beyond ±{STEPS_TOLERANCE:.0%}.", "",
             "| run | worst | per epoch |", "|---|---|---|"]
    for name, values in [*runs.items(), *free.items()]:
        gaps = [(round(abs(v / reference[i] - 1), 6), i + 1, v / reference[i] - 1)
                for i, v in enumerate(values)
                if i >= 1 and v == v and reference[i] == reference[i] and reference[i] > 0]
        worst = max(gaps, default=(0.0, 0, 0.0))
        mark = " ✗" if worst[0] > STEPS_TOLERANCE else ""
        where = f"{worst[2]:+.1%} at epoch {worst[1]}" if worst[0] > 0 else "none"
        lines.append(f"| {name} | {where}{mark} | "
                     f"{', '.join(f'{v:.2f}' for v in values)} |")
    lines.append(f"| fault-free median | – | {', '.join(f'{v:.2f}' for v in reference)} |")
    return lines


def write_report(records: list[dict[str, Any]], *, task: str, method: str, work: Path,
                 committed: Path | None, baselines: list[Path] | None, window: int, out: Path,
                 command: str) -> bool:
    """chaos.md and chaos.json in `out`: the soaks just run and every committed soak of
    `task` and `method`, against `baselines` (default: the fault-free seeds committed or
    under `work`). Returns whether every soak kept every promise."""
    stem = f"{task}-{method}-s"
    roots = [committed, work / "runs"]
    chaos = {r["name"]: r for r in records if r["chaos_seed"] is not None}
    for name, folder in _folders(roots, f"chaos*-{stem}*").items():
        if name not in chaos and (record := _load(folder)) is not None:
            chaos[name] = record
    quick = any(r["quick"] for r in records)  # quick runs are never mixed with soaks
    chaos = {n: r for n, r in chaos.items() if r["quick"] == quick}
    free = (_folders(roots, f"nofault-{stem}*") if baselines is None else
            {p.name: p for p in baselines})
    curves = {name: success_curve(folder) for name, folder in free.items()}
    curves = {name: curve for name, curve in curves.items() if curve}
    free_records = [r for folder in free.values() if (r := _load(folder)) is not None]
    config_notes = []
    for name in chaos:
        run = next((f for f in (work / "runs" / name,
                                None if committed is None else committed / name)
                    if f is not None and f.is_dir()), None)
        for other, folder in free.items():
            if run is not None and (diff := config_differences(run, folder)):
                config_notes.append(f"{name} and {other} differ in configuration: "
                                    f"{'; '.join(diff)}")
    full = ["python -m bench.faults.chaos --fault-free 1 2 3   # the envelope: 3 fault-free seeds",
            "python -m bench.faults.chaos                      # the soak: chaos seed 1, "
            "training seed 1",
            "python -m bench.faults.chaos --report-only        # this file, from "
            "docs/results/runs/"]
    text, ok = report(sorted(chaos.values(), key=lambda r: r["name"]), curves, free_records,
                      command=command, window=window, config_notes=config_notes,
                      full_commands=full,
                      validation=VALIDATION if (out / VALIDATION).is_file() else "")
    soak_folders = _folders(roots, f"chaos*-{stem}*")
    text += "\n".join(_steps_section(
        {n: steps_per_update(soak_folders[n]) for n in sorted(chaos) if n in soak_folders},
        {n: steps_per_update(folder) for n, folder in sorted(free.items())})) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "chaos.md").write_text(text)
    (out / "chaos.json").write_text(json.dumps(
        {"soaks": sorted(chaos.values(), key=lambda r: r["name"]),
         "fault_free": {n: {"success": c} for n, c in curves.items()}}, indent=1) + "\n")
    print(f"chaos: wrote {out / 'chaos.md'}{'' if ok else ' (a promise was broken)'}",
          flush=True)
    return ok
