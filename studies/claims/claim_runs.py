"""Committed runs as the claims read them: grouped by what their config.yaml says (everything
but the seed; *legacy* and *new default* lag settings told apart) and scored per run with
hercs/apps/plots/curves.py's rule (success after EPOCH, epoch at 0.5, censored at EPOCH). The
rules: docs/results/claims.md.
"""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass, replace
from pathlib import Path

import yaml

from hercs.apps.plots.curves import (
    Curve,
    aggregate,
    energy_epsilon,
    load_reference,
    marks_epsilon,
    method_label,
    milestones,
    task_title,
)
from hercs.config import HercsConfig
from hercs.run.rundir import RunDir
from studies.authors_peer import PEER_SCHEDULE
from studies.claims.claim_statistics import (
    Score,
)
from studies.run_curves import load_runs

EPOCH = 50
THRESHOLD = 0.5
HIGH = 0.9
"""The second milestone, where a task is close to solved (PickAndPlace's runs pass it by
epoch 100; few Push runs do by 50)."""
DONE_FILE = "bench_done.json"
"""`hercs sweep`'s record of a finished run (hercs/apps/sweep/runner.py): commit, time, machine."""
ASSUMED_KEYS: tuple[tuple[str, str, str], ...] = (
    ("training", "schedule", "async"), ("learner", "precision", "fp32"))
"""Settings that older config.yaml files lack; such a run is grouped with these values (the
only ones that existed when it was made), and the report says so."""
NOTES_FILE = "notes.md"
"""What a committed run's files need said that they cannot say themselves, written by hand in
the run's folder (docs/results/runs/<run>/notes.md: a heading, then the note); the claims'
report lists it with the run."""
MIN_SEEDS = 2
LEGACY = "legacy"
POOLED = "pooled"
"""The schedule of a side pooled from the runs of several groups (studies/claims/claims.py's
POOLS); its `setting` names what was pooled."""
LEGACY_LAG_CYCLES = 7  # docs/results/runs/README.md: the median policy lag of the legacy runs
LAG_KEYS: tuple[tuple[str, str], ...] = (
    ("learner", "prefetch_depth"), ("training", "max_policy_lag"), ("actor", "insert_queue"))
"""The settings that bound an asynchronous run's policy lag; the first two mark a run as made
after the legacy default."""
DEFAULT_ENV = "v4"


# ---------------------------------------------------------------------------------- groups

@dataclass(frozen=True)
class Group:
    """What makes runs seeds of one experiment: everything but the seed."""

    task: str  # display name, "FetchPush"
    method: str  # her, her-cs, her-ebp, her-ebp-cs
    env: str = DEFAULT_ENV  # task.env_version
    schedule: str = "async"  # training.schedule; "authors" for the published curves
    precision: str = "fp32"  # learner.precision
    lag: str = ""  # asynchronous only: LEGACY or "prefetch_depth=3, max_policy_lag=…, …"
    setting: str = ""  # other experiment settings: "torquescale 4", "ε 0.001"

    @property
    def label(self) -> str:
        """"HER-CS, v4, async (legacy), fp32"; "HER-CS, authors' (v1)"."""
        name = method_label(self.method)
        if self.schedule == "authors":
            return f"{name}, authors' ({self.env})"
        if self.schedule == POOLED:
            return f"{name}, {self.env}: {self.setting}"
        if self.schedule == PEER_SCHEDULE:  # their code's arithmetic: fp32 on our CPUs
            marked = f", {self.precision}" if self.precision != "fp32" else ""
            return f"{name}, authors' code on our {self.env}{marked}"
        schedule = f"async ({lag_label(self.lag)})" if self.schedule == "async" else self.schedule
        setting = f", {self.setting}" if self.setting else ""
        return f"{name}, {self.env}, {schedule}, {self.precision}{setting}"


@functools.cache
def new_default_lag() -> str:
    """The lag setting of a run made with hercs.config's defaults today."""
    config = HercsConfig()
    return lag_setting({section: {key: getattr(getattr(config, section), key, None)}
                        for section, key in LAG_KEYS})


def lag_setting(config: dict) -> str:
    """LEGACY for a config.yaml from before `learner.prefetch_depth` and
    `training.max_policy_lag` existed, else the values of LAG_KEYS."""
    values = [(key, (config.get(section) or {}).get(key)) for section, key in LAG_KEYS]
    if all(value is None for _, value in values[:2]):
        return LEGACY
    return ", ".join(f"{key}={value}" for key, value in values)


def lag_label(lag: str) -> str:
    return "new default" if lag == new_default_lag() else lag


def group_of(config: dict) -> Group:
    """A run's group from its config.yaml (task.name, run.method present: load_run checked)."""
    task, run = config.get("task") or {}, config.get("run") or {}
    schedule = (config.get("training") or {}).get("schedule", "async")
    return Group(task=task_title(task["name"]), method=run["method"],
                 env=task.get("env_version", DEFAULT_ENV), schedule=schedule,
                 precision=(config.get("learner") or {}).get("precision", "fp32"),
                 lag=lag_setting(config) if schedule == "async" else "",
                 setting=experiment_setting(config))


def experiment_setting(config: dict) -> str:
    """What else a run's config.yaml changes that makes it another experiment than its
    method's: the v4 weld's torquescale other than 1, an EBP method's ε other than 1e-6
    (plots.marks_epsilon) and a cluster share rule other than every-cluster ("" for none), so
    that such a run is never taken for a seed of the plain group."""
    scale = float((config.get("task") or {}).get("weld_torquescale", 1.0))
    eps = energy_epsilon(config)
    method = str((config.get("run") or {}).get("method", ""))
    rule = str((config.get("cluster") or {}).get("share_rule", "every-cluster"))
    return ", ".join(s for s in (f"torquescale {scale:g}" if scale != 1.0 else "",
                                 f"ε {eps:g}" if marks_epsilon(method, eps) else "",
                                 f"{rule} share rule" if rule != "every-cluster" else "")
                     if s)


@dataclass(frozen=True)
class Run:
    name: str  # the run folder's name, or "authors seed 121"
    seed: int
    epochs: int  # the last epoch it reached
    curve: Curve
    commit: str = ""  # `provenance`'s: "started→finished" where they differ, "" where not recorded
    finished: str = ""  # its UTC date, YYYY-MM-DD
    machine: str = ""  # "AMD EPYC (avx2), boot 5011c83b"; "" where not recorded
    assumed: tuple[str, ...] = ()
    """ASSUMED_KEYS its config.yaml lacks ("training.schedule=async")."""
    note: str = ""  # its NOTES_FILE's text, on one line; "" where it has none


UNKNOWN = "unknown"
"""The start commit of a resumed run made before it was recorded."""


def provenance(run_dir: Path, config: dict) -> dict[str, str]:
    """commit, finished and machine from the run's bench_done.json ("" where absent). The
    commit is "started→finished" where a run started on another commit than it ended on: the
    start from bench_done.json's `started_commit` (`hercs sweep`) or config.yaml's
    `peer.started_commit` (studies/authors_peer), UNKNOWN for a run bench_done.json marks
    `resumed` that records neither."""
    path = run_dir / DONE_FILE
    try:
        done = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        done = {}
    machine = done.get("machine") or {}
    cpu = str(machine.get("cpu") or "")
    label = ""
    if cpu:
        name, _, rest = cpu.replace("(R)", "").partition(" (")
        flags = rest.rstrip(")").partition("; ")[2].split()
        vector = "avx512" if "avx512f" in flags else ("avx2" if "avx2" in flags else "")
        label = f"{name}{f' ({vector})' if vector else ''}"
        if machine.get("boot_id"):
            label += f", boot {machine['boot_id']}"

    def short(value: object) -> str:
        return str(value or "").replace(" (with uncommitted changes)", "+")

    commit = short(done.get("commit"))
    started = short(done.get("started_commit")
                    or (config.get("peer") or {}).get("started_commit"))
    if commit and not started and done.get("resumed"):
        started = UNKNOWN
    if started and started != commit:  # a resumed run that finished with other code
        commit = f"{started}→{commit}"
    return {"commit": commit, "finished": str(done.get("finished") or "")[:10],
            "machine": label}


def run_note(run_dir: Path) -> str:
    """The run's NOTES_FILE without its heading, on one line ("" where there is none)."""
    path = run_dir / NOTES_FILE
    if not path.is_file():
        return ""
    text = "\n".join(line for line in path.read_text().splitlines() if not line.startswith("#"))
    return " ".join(text.split())


def assumed_settings(config: dict) -> tuple[str, ...]:
    return tuple(f"{section}.{key}={value}" for section, key, value in ASSUMED_KEYS
                 if key not in (config.get(section) or {}))


def load_groups(runs_dir: Path, reference_csv: Path | None = None) -> Groups:
    """Our runs under `runs_dir` (folders that are not runs are passed over) and the
    authors' curves, by group, each group's runs by seed. Two runs of one group and seed are
    one seed: the longer is kept, as in `hercs plot`."""
    found: list[tuple[Group, Run]] = []
    for curve in load_runs(runs_dir):
        source = Path(curve.source)
        config = yaml.safe_load(RunDir(source).config.read_text()) or {}
        found.append((group_of(config), Run(source.name, curve.seed, int(curve.epochs.max()),
                                            curve, **provenance(source, config),
                                            assumed=assumed_settings(config),
                                            note=run_note(source))))
    reference = load_reference() if reference_csv is None else load_reference(reference_csv)
    for curve in reference:
        found.append((Group(curve.task, curve.method, env="v1", schedule="authors"),
                      Run(f"authors seed {curve.seed}", curve.seed, int(curve.epochs.max()),
                          curve)))
    by_seed: dict[tuple[Group, int], Run] = {}
    for g, run in found:
        kept = by_seed.get((g, run.seed))
        if kept is None or run.epochs > kept.epochs:
            by_seed[(g, run.seed)] = run
    out = Groups()
    for (g, _), run in sorted(by_seed.items(), key=lambda kv: (kv[0][1], kv[1].name)):
        out.setdefault(g, []).append(run)
    out.dropped = sorted((run.name, by_seed[(g, run.seed)].name) for g, run in found
                         if by_seed[(g, run.seed)] is not run)
    return out


class Groups(dict[Group, list[Run]]):
    """Runs by group and seed (`load_groups`), and the runs of a group and seed that a longer
    one replaced: `dropped`, (run, the run counted instead) pairs."""

    def __init__(self) -> None:
        super().__init__()
        self.dropped: list[tuple[str, str]] = []


# ---------------------------------------------------------------------------------- scores

def score(run: Run, epoch: int = EPOCH) -> Score | None:
    """`run`'s numbers with its curve cut at `epoch`; None when it did not reach it."""
    c = run.curve
    keep = c.epochs <= epoch
    if not keep.any() or int(c.epochs[keep].max()) != epoch:
        return None
    cut = replace(c, epochs=c.epochs[keep], success=c.success[keep])
    m = milestones(aggregate([cut]), thresholds=(THRESHOLD, HIGH), at_epochs=(epoch,))
    at, high, success = m.crossing[THRESHOLD], m.crossing[HIGH], m.at[epoch]
    assert success is not None
    return Score(run.name, success, epoch if at is None else at, at is None,
                 epoch if high is None else high, high is None)

