"""The project's claims as the field states them: IQM and mean over seeds with stratified
bootstrap intervals, and the probability of improvement (rliable, Agarwal et al. 2021).

    python -m studies.claims          # committed runs + the authors' curves →
    docs/results/claims.md

Reads finished runs (config.yaml + metrics.csv) from `--runs` (default docs/results/runs/, the
committed ones) and the authors' per-seed curves (docs/reference/authors_success_rates.csv).

Runs are grouped by what their config.yaml says: task.name, task.env_version (absent: v4,
the only environment before the setting existed), run.method, training.schedule,
learner.precision and, for the asynchronous schedule, the policy-lag setting: a config
without `learner.prefetch_depth` and `training.max_policy_lag` is *legacy* (the old default,
whose measured policy lag was 7 cycles); one with them is grouped by their values (and
`actor.insert_queue`'s), and the values equal to hercs.config's defaults are the *new
default*. A claim whose sides run asynchronously takes the new default when every
asynchronous side has at least MIN_SEEDS runs of it, else the legacy runs, and says which.

Per run, with hercs/apps/plots.py's rule (the Fig. 2 tables'): its success after epoch EPOCH (the
10-epoch trailing mean there) and the epoch its 10-epoch trailing mean first exceeds 0.5,
counted from 0; a run that never does by epoch EPOCH counts as EPOCH, one more than the
last epoch in that count (censored: a lower bound). Every run is cut at EPOCH (the authors'
too), and a run with fewer epochs is left out. Per side: IQM and mean with 95 % stratified
bootstrap percentile intervals (rliable.library.get_interval_estimates); per claim: the
probability of improvement P(X > Y) (rliable.metrics.probability_of_improvement) with its
interval from resampling each side on its own. A side with fewer than MIN_SEEDS runs gets no
numbers. The output is a pure function of the runs (fixed reps and RNG seed, no date), so a
test checks the committed file against them.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import yaml

from hercs.apps.plots import (
    EPSILON_DEFAULT,
    Curve,
    aggregate,
    energy_epsilon,
    load_reference,
    load_runs,
    method_label,
    milestones,
    task_title,
)
from hercs.config import HercsConfig
from hercs.run.rundir import RunDir
from studies.claims.claim_statistics import (
    REPS,
    RNG_SEED,
    EpochStats,
    Estimate,
    Score,
    SideStats,
    epoch_stats,
    improvement,
    side_stats,
)

REPO = Path(__file__).resolve().parents[2]

OUTPUT = "claims.md"
EPOCH = 50
THRESHOLD = 0.5
HIGH = 0.9
"""The second milestone, where a task is close to solved (PickAndPlace's runs pass it by
epoch 100; few Push runs do by 50)."""
DONE_FILE = "bench_done.json"
"""`hercs sweep`'s record of a finished run (hercs/apps/sweep.py): commit, time, machine."""
ASSUMED_KEYS: tuple[tuple[str, str, str], ...] = (
    ("training", "schedule", "async"), ("learner", "precision", "fp32"))
"""Settings that older config.yaml files lack; such a run is grouped with these values (the
only ones that existed when it was made), and the report says so."""
RUN_NOTES: dict[str, str] = {
    "push-her-lag7-s2": (
        "its `policy_lag` reads 60 for epochs 21–50, against 7 before. It was stopped at "
        "epoch 20 and resumed; the replay kept the 212 episodes acted between the learner's "
        "last checkpoint and the stop (acknowledged data is never dropped). `policy_lag` "
        "counts episode ids against the lockstep schedule, so those 212 episodes (53 cycles "
        "of 4) shift it by 53 for the rest of the run: it measures the kept data against "
        "the schedule, not staleness. The lag against the learner's current weights "
        "(`policy_lag_request`) was 1.0 cycle before the stop and after it. The run saw "
        "10,600 more environment steps than its schedule (2 % of 500,000 by epoch 50), all "
        "in epoch 21. No claim here counts it: the new default's HER seeds replace the "
        "legacy ones."),
}
"""What a committed run's files need said that they cannot say themselves."""
MIN_SEEDS = 2
LEGACY = "legacy"
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
    method's: the v4 weld's torquescale and EBP's ε where not the defaults ("" for none), so
    that such a run is never taken for a seed of the plain group."""
    scale = float((config.get("task") or {}).get("weld_torquescale", 1.0))
    eps = energy_epsilon(config)
    return ", ".join(s for s in (f"torquescale {scale:g}" if scale != 1.0 else "",
                                 f"ε {eps:g}" if eps != EPSILON_DEFAULT else "") if s)


@dataclass(frozen=True)
class Run:
    name: str  # the run folder's name, or "authors seed 121"
    seed: int
    epochs: int  # the last epoch it reached
    curve: Curve
    commit: str = ""  # bench_done.json's, "" where not recorded
    finished: str = ""  # its UTC date, YYYY-MM-DD
    machine: str = ""  # "AMD EPYC (avx2), boot 5011c83b"; "" where not recorded
    assumed: tuple[str, ...] = ()
    """ASSUMED_KEYS its config.yaml lacks ("training.schedule=async")."""


def provenance(run_dir: Path) -> dict[str, str]:
    """commit, finished and machine from the run's bench_done.json ("" where absent)."""
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
    commit = str(done.get("commit") or "").replace(" (with uncommitted changes)", "+")
    return {"commit": commit, "finished": str(done.get("finished") or "")[:10],
            "machine": label}


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
                                            curve, **provenance(source),
                                            assumed=assumed_settings(config))))
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


# ---------------------------------------------------------------------------------- claims

ASYNC_ANY_LAG = "?"  # a claim side in the asynchronous schedule whose lag setting is chosen


@dataclass(frozen=True)
class Claim:
    title: str
    x: Group
    y: Group
    epoch: int | None = None
    """Where both sides are cut, when not at the report's epoch (EPOCH): for runs that were
    made shorter; the title says so."""


def _push(method: str, **kw: str) -> Group:
    lag = kw.pop("lag", ASYNC_ANY_LAG if kw.get("schedule", "async") == "async" else "")
    return Group("FetchPush", method, lag=lag, **kw)


def _pick(method: str, **kw: str) -> Group:
    lag = kw.pop("lag", ASYNC_ANY_LAG if kw.get("schedule", "async") == "async" else "")
    return Group("FetchPickAndPlace", method, lag=lag, **kw)


PICK_EPOCH = 100
"""PickAndPlace's claims are read at epoch 100, where the authors' own seeds separate HER-CS
from HER (P .96); at the report's EPOCH they do not yet."""

CLAIMS: tuple[Claim, ...] = (
    Claim("environment v1 against v4, HER-EBP-CS", _push("her-ebp-cs", env="v1"),
          _push("her-ebp-cs")),
    Claim("HER-CS against HER, v1", _push("her-cs", env="v1"), _push("her", env="v1")),
    Claim("HER-CS against HER, v4", _push("her-cs"), _push("her")),
    # what the paper's own 5 seeds a side give under the same statistics: the yardstick for
    # how many seeds the claim needs
    Claim("HER-CS against HER, the authors' (v1)",
          _push("her-cs", env="v1", schedule="authors", lag=""),
          _push("her", env="v1", schedule="authors", lag="")),
    Claim("lockstep against asynchronous, HER-CS", _push("her-cs", schedule="lockstep"),
          _push("her-cs")),
    Claim("bf16 against fp32, HER-EBP-CS, at epoch 40 (the bf16 runs' length)",
          _push("her-ebp-cs", precision="bf16"), _push("her-ebp-cs"), epoch=40),
    # EBP's floor: the authors' simulator gave still-cube episodes ~1e-3 of energy (docs/
    # results/early_policy.md part 4); ε 1e-3 on v4 restores that share of the draws
    Claim("energy ε 1e-3 against the default, HER-EBP-CS, v4",
          _push("her-ebp-cs", setting="ε 0.001"), _push("her-ebp-cs")),
    Claim("v4 with ε 1e-3 against v1, HER-EBP-CS: does the setting close the gap?",
          _push("her-ebp-cs", setting="ε 0.001"), _push("her-ebp-cs", env="v1")),
    Claim("ours against the authors', HER-EBP-CS, v4 with ε 1e-3",
          _push("her-ebp-cs", setting="ε 0.001"),
          _push("her-ebp-cs", env="v1", schedule="authors", lag="")),
    *(Claim(f"ours against the authors', {method_label(m)}, {env}", _push(m, env=env),
            _push(m, env="v1", schedule="authors", lag=""))
      for env in ("v4", "v1") for m in ("her", "her-cs", "her-ebp", "her-ebp-cs")),
    # PickAndPlace at epoch 100: where the paper's evidence is strongest
    Claim("PickAndPlace: HER-CS against HER, the authors' (v1), at epoch 100",
          _pick("her-cs", env="v1", schedule="authors", lag=""),
          _pick("her", env="v1", schedule="authors", lag=""), epoch=PICK_EPOCH),
    *(Claim(f"PickAndPlace: HER-CS against HER, {env}, at epoch 100",
            _pick("her-cs", env=env), _pick("her", env=env), epoch=PICK_EPOCH)
      for env in ("v1", "v4")),
    *(Claim(f"PickAndPlace: ours against the authors', {method_label(m)}, {env}, at epoch 100",
            _pick(m, env=env), _pick(m, env="v1", schedule="authors", lag=""),
            epoch=PICK_EPOCH)
      for env in ("v1", "v4") for m in ("her", "her-cs")),
    *(Claim(f"PickAndPlace: environment v1 against v4, {method_label(m)}, at epoch 100",
            _pick(m, env="v1"), _pick(m), epoch=PICK_EPOCH)
      for m in ("her", "her-cs")),
)


@dataclass(frozen=True)
class Side:
    group: Group
    scores: list[Score]
    short: list[str]
    """Runs of the group left out: they stopped before `epoch`."""
    epoch: int = EPOCH
    """Where its runs were cut."""

    @property
    def n(self) -> int:
        return len(self.scores)


@dataclass(frozen=True)
class ClaimResult:
    claim: Claim
    x: Side
    y: Side
    x_stats: SideStats | None
    y_stats: SideStats | None
    improvement: tuple[Estimate, Estimate] | None
    """None unless both sides have MIN_SEEDS runs."""
    high: EpochStats | None = None
    """The epoch at HIGH; None unless both sides have MIN_SEEDS runs."""


def _side(groups: dict[Group, list[Run]], g: Group, epoch: int) -> Side:
    scores, short = [], []
    for run in groups.get(g, []):
        s = score(run, epoch)
        if s is None:
            short.append(run.name)
        else:
            scores.append(s)
    return Side(g, scores, short, epoch)


def resolve(claim: Claim, groups: dict[Group, list[Run]], epoch: int = EPOCH
            ) -> tuple[Side, Side]:
    """The claim's sides, an asynchronous side's lag setting chosen (the same for both):
    the new default where every asynchronous side has MIN_SEEDS runs of it, else the legacy
    runs where they do; failing both, the setting that has runs at all, the new default
    first."""
    def sides(lag: str) -> tuple[Side, Side]:
        x, y = (_side(groups, replace(g, lag=lag) if g.lag == ASYNC_ANY_LAG else g, epoch)
                for g in (claim.x, claim.y))
        return x, y

    chosen = [i for i, g in enumerate((claim.x, claim.y)) if g.lag == ASYNC_ANY_LAG]
    candidates = [sides(new_default_lag()), sides(LEGACY)] if chosen else [sides("")]
    for ok in (lambda s: s.n >= MIN_SEEDS, lambda s: bool(s.scores or s.short)):
        for pair in candidates:
            if all(ok(pair[i]) for i in chosen):
                return pair
    return candidates[0]


def _highs(side: Side) -> list[int]:
    """The side's epochs at HIGH (score() always sets them)."""
    return [s.at_high if s.at_high is not None else side.epoch for s in side.scores]


def evaluate(claims: Sequence[Claim], groups: dict[Group, list[Run]], epoch: int = EPOCH,
             reps: int = REPS, seed: int = RNG_SEED) -> list[ClaimResult]:
    cache: dict[tuple[Score, ...], SideStats] = {}

    def stats_of(side: Side) -> SideStats | None:
        if side.n < MIN_SEEDS:
            return None
        key = tuple(side.scores)
        if key not in cache:
            cache[key] = side_stats(side.scores, reps, seed)
        return cache[key]

    out = []
    for claim in claims:
        x, y = resolve(claim, groups, claim.epoch or epoch)
        both = x.n >= MIN_SEEDS and y.n >= MIN_SEEDS
        high = epoch_stats(_highs(x), _highs(y), reps, seed) if both else None
        out.append(ClaimResult(claim, x, y, stats_of(x), stats_of(y),
                               improvement(x.scores, y.scores, reps, seed) if both else None,
                               high))
    return out


# ---------------------------------------------------------------------------------- report

def _rate(v: float) -> str:
    text = f"{v:.2f}"
    return text[1:] if text.startswith("0") else text.replace("-0.", "-.")


def _epoch(v: float) -> str:
    return f"{v:.1f}"


def _est(e: Estimate, fmt: Callable[[float], str]) -> str:
    return f"{fmt(e.value)} [{fmt(e.low)}, {fmt(e.high)}]"


def _not_enough(r: ClaimResult) -> str:
    parts = []
    for name, side in (("X", r.x), ("Y", r.y)):
        if side.n < MIN_SEEDS:
            short = (f", {len(side.short)} shorter than {side.epoch} epochs" if side.short
                     else "")
            parts.append(f"{name} n={side.n}{short}")
    return f"not enough seeds ({'; '.join(parts)})"


def _rows(results: Sequence[ClaimResult], which: str) -> list[str]:
    lines = []
    for r in results:
        head = f"| {r.claim.title} | {r.x.group.label} | {r.y.group.label} | {r.x.n} / {r.y.n} |"
        if which in ("epoch", "high"):
            cx, cy = (sum(s.censored_high if which == "high" else s.censored
                          for s in side.scores) for side in (r.x, r.y))
            head += f" {cx} / {cy} |"
        if r.x_stats is None or r.y_stats is None or r.improvement is None or r.high is None:
            lines.append(head + f" {_not_enough(r)} | – | – | – | – |")
            continue
        if which == "high":
            h = r.high
            cells = [_est(e, _epoch) for e in (h.x_iqm, h.y_iqm, h.x_mean, h.y_mean)]
            lines.append(head + " " + " | ".join(cells) + f" | {_est(h.earlier, _rate)} |")
            continue
        if which == "success":
            cells = [_est(st.success_iqm, _rate) for st in (r.x_stats, r.y_stats)]
            cells += [_est(st.success_mean, _rate) for st in (r.x_stats, r.y_stats)]
            poi = r.improvement[0]
        else:
            cells = [_est(st.epoch_iqm, _epoch) for st in (r.x_stats, r.y_stats)]
            cells += [_est(st.epoch_mean, _epoch) for st in (r.x_stats, r.y_stats)]
            poi = r.improvement[1]
        lines.append(head + " " + " | ".join(cells) + f" | {_est(poi, _rate)} |")
    return lines


def _groups_section(results: Sequence[ClaimResult], groups: dict[Group, list[Run]],
                    epoch: int) -> list[str]:
    lines = [f"## The runs behind each side, at epoch {epoch}", "",
             f"| side | run | success after {epoch} | epoch at {THRESHOLD:g} | "
             f"epoch at {HIGH:g} |",
             "|---|---|---|---|---|"]
    seen: set[Group] = set()
    listed: set[tuple[Group, int]] = set()
    for r in results:
        for side in (r.x, r.y):
            seen.add(side.group)
            if (side.group, side.epoch) in listed or not (side.scores or side.short):
                continue
            listed.add((side.group, side.epoch))
            label = side.group.label + (f" (at epoch {side.epoch})" if side.epoch != epoch
                                        else "")
            for s in side.scores:
                at = f"never ({side.epoch}, censored)" if s.censored else str(s.at_half)
                high = (f"never ({side.epoch}, censored)" if s.censored_high
                        else str(s.at_high))
                lines.append(f"| {label} | {s.run} | {_rate(s.success)} | {at} | {high} |")
            for name in side.short:
                lines.append(f"| {label} | {name} | stopped before epoch {side.epoch}: "
                             "left out | – | – |")
    unused = sorted((run.name, f"its group is in no claim ({g.task}, {g.label})")
                    for g, runs in groups.items() if g not in seen and g.schedule != "authors"
                    for run in runs)
    unused += [(name, f"a longer run of its group and seed is counted: {kept}")
               for name, kept in getattr(groups, "dropped", [])]
    if unused:
        lines += ["", "**Committed runs in no claim**, and why:", "", "| run | why |",
                  "|---|---|", *(f"| {name} | {why} |" for name, why in sorted(unused))]
    return [*lines, ""]


def _sides(results: Sequence[ClaimResult]) -> list[Side]:
    """Every side with runs, once, in the order the claims name them."""
    out: list[Side] = []
    seen: set[tuple[Group, int]] = set()
    for r in results:
        for side in (r.x, r.y):
            if (side.group, side.epoch) not in seen and side.scores:
                seen.add((side.group, side.epoch))
                out.append(side)
    return out


def _provenance_section(results: Sequence[ClaimResult], groups: dict[Group, list[Run]]
                        ) -> list[str]:
    """Per side: the commits, dates and machines its runs were made on (from each run's
    bench_done.json), and the settings assumed for old configs."""
    by_name = {run.name: run for runs in groups.values() for run in runs}
    lines = ["## Where each side's runs were made", "",
             "From each run's bench_done.json (`hercs sweep` writes it as a run "
             "ends): the hercs commit (+: with uncommitted changes), the day it finished "
             "(UTC) and the machine (CPU and vector extensions, boot id; where bench_done.json "
             "has none, docs/results/runs/README.md's table describes it in words). A side's "
             "runs are "
             "seeds of one experiment, but not always of one commit or machine: a seed gives "
             "other numbers on another CPU (docs/DESIGN.md §10).", "",
             "| side | runs | commits | finished | machines | settings assumed |",
             "|---|---|---|---|---|---|"]
    for side in _sides(results):
        if side.group.schedule == "authors":
            lines.append(f"| {side.group.label}{_at(side)} | {side.n} | the authors' "
                         "published curves (docs/reference/authors_success_rates.csv) | – | "
                         "– | – |")
            continue
        runs = [by_name[s.run] for s in side.scores]

        def listed(values: list[str]) -> str:
            known = sorted(set(v for v in values if v))
            missing = sum(1 for v in values if not v)
            parts = [*known, *([f"not recorded ({missing})"] if missing else [])]
            return ", ".join(parts)

        dates = sorted(r.finished for r in runs if r.finished)
        span = (f"{dates[0]} – {dates[-1]}" if dates and dates[0] != dates[-1]
                else (dates[0] if dates else "not recorded"))
        assumed = sorted({a for r in runs for a in r.assumed})
        assumed_cell = (", ".join(f"{a} ({_runs(sum(a in r.assumed for r in runs))})"
                                  for a in assumed) if assumed else "none")
        lines.append(f"| {side.group.label}{_at(side)} | {side.n} | "
                     f"{listed([r.commit for r in runs])} | {span} | "
                     f"{listed([r.machine for r in runs])} | {assumed_cell} |")
    assumed_runs = sorted(run.name for runs in groups.values() for run in runs if run.assumed)
    if assumed_runs:
        lines += ["", f"*Settings assumed*: {', '.join(assumed_runs)} predate "
                  f"{' and '.join(f'`{s}.{k}`' for s, k, _ in ASSUMED_KEYS)} in config.yaml "
                  "and are grouped with the only values there were then "
                  f"({', '.join(f'{v}' for _, _, v in ASSUMED_KEYS)})."]
    notes = [(name, note) for name, note in sorted(RUN_NOTES.items()) if name in by_name]
    if notes:
        lines += ["", "**Notes on runs**", "", *(f"- **{name}**: {note}" for name, note in notes)]
    return [*lines, ""]


def _runs(n: int) -> str:
    return f"{n} run{'' if n == 1 else 's'}"


def _at(side: Side) -> str:
    return f" (at epoch {side.epoch})" if side.epoch != EPOCH else ""


def _seed_range(results: Sequence[ClaimResult]) -> str:
    ns = sorted({side.n for side in _sides(results) if side.n >= MIN_SEEDS})
    if not ns:
        return f"{MIN_SEEDS} or more"
    return f"{ns[0]}–{ns[-1]}" if ns[0] != ns[-1] else str(ns[0])


def report(results: Sequence[ClaimResult], groups: dict[Group, list[Run]], command: str,
           epoch: int = EPOCH, reps: int = REPS, seed: int = RNG_SEED) -> str:
    lines = [
        "# The claims, with intervals over seeds", "",
        f"Drawn by `{command}` from the committed runs (docs/results/runs/) and the authors' "
        "per-seed curves (docs/reference/authors_success_rates.csv); also `make figures`, and "
        "a test checks this file against them. All on FetchPush, but for the PickAndPlace "
        f"lines, which are read at epoch {PICK_EPOCH}.", "",
        "**Per run** (hercs/apps/plots.py's rule, the Fig. 2 tables'): *success after epoch "
        f"{epoch}*, the 10-epoch trailing mean of the test success there; *epoch at "
        f"{THRESHOLD:g}*, the first epoch whose 10-epoch trailing mean exceeds {THRESHOLD:g}, "
        f"counted from 0 (epochs completed before it), and likewise the *epoch at {HIGH:g}*. "
        f"A run that never does by epoch {epoch} "
        f"counts as {epoch}, one more than its last epoch in that count: **censored**, a lower "
        "bound, so the IQM and mean of a side with censored runs are lower bounds too (the "
        f"table counts them). Every run is cut at epoch {epoch}, the authors' too (a claim "
        "whose title names another epoch is cut there, both sides); a run that stopped "
        "before its claim's epoch is left out.", "",
        "**Per side**: the IQM (interquartile mean, rliable's `aggregate_iqm`: the mean of the "
        "middle 50 % of runs; below 4 runs it trims nothing and equals the mean) and the mean, "
        "each with a 95 % stratified bootstrap percentile interval over runs "
        f"(`rliable.library.get_interval_estimates`, {reps:,} reps; rliable draws its "
        f"resamples from numpy's global RNG, seeded with {seed} for each estimate). **Per "
        "claim**: P(X > Y), the probability that a run of X beats a run of Y, ties counted "
        "half (`rliable.metrics.probability_of_improvement`: Mann–Whitney U / (n_X·n_Y)), "
        "with a 95 % interval from resampling each side's runs on its own (rliable's "
        "independent stratified bootstrap), same reps and seed; for the epoch at "
        f"{THRESHOLD:g}, beating is getting there earlier, and two censored runs tie. The "
        "point estimates are rliable's functions'; inside the bootstrap, numpy equivalents "
        "(equal to them, tests/studies/claims/test_claims.py) stand in for them, scipy's per-call "
        f"cost being most of its time. A side with fewer than {MIN_SEEDS} seeds gets no "
        "numbers.", "",
        "**Groups**: runs are seeds of one experiment when their config.yaml agrees on "
        "task.name, task.env_version (absent: v4; v1 is the authors' gym/mujoco-py "
        "environment), run.method, training.schedule and learner.precision, and, when "
        "asynchronous, on the policy-lag setting: *legacy* (no `learner.prefetch_depth` and "
        f"`training.max_policy_lag` in the config: the old default, policy lag "
        f"{LEGACY_LAG_CYCLES} cycles) or the values of those two and `actor.insert_queue` "
        "(*new default*: hercs.config's defaults). A claim takes the new default's runs where "
        f"every asynchronous side has {MIN_SEEDS} seeds of it, else the legacy ones; each "
        "side says which.", "",
        f"**How far to trust them**: with {_seed_range(results)} seeds a side the bootstrap "
        "can only resample the "
        "seeds there are, so an interval describes these seeds and is narrower than the "
        "uncertainty about the next one (a percentile bootstrap undercovers at such n): an "
        "interval of P(X > Y) that excludes .5 is a lead, not a verdict. The runs also come "
        "from different machines and commits (the last section says which, per side), and "
        "one seed gives other numbers on another CPU (docs/DESIGN.md §10).", "",
        f"## Success after epoch {epoch}", "",
        "| claim | X | Y | seeds X / Y | X: IQM [95 % CI] | Y: IQM [95 % CI] | "
        "X: mean [95 % CI] | Y: mean [95 % CI] | P(X > Y) [95 % CI] |",
        "|---|---|---|---|---|---|---|---|---|",
        *_rows(results, "success"), "",
        f"## Epoch at which the 10-epoch mean first exceeds {THRESHOLD:g}", "",
        f"Censored: runs that never did by epoch {epoch}, counted as {epoch}. "
        "P(X earlier): the probability that a run of X gets there before a run of Y.", "",
        "| claim | X | Y | seeds X / Y | censored X / Y | X: IQM [95 % CI] | Y: IQM [95 % CI] | "
        "X: mean [95 % CI] | Y: mean [95 % CI] | P(X earlier) [95 % CI] |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *_rows(results, "epoch"), "",
        f"## Epoch at which the 10-epoch mean first exceeds {HIGH:g}", "",
        f"As above, for {HIGH:g}: close to solved. Censored: runs that never did by their "
        "claim's epoch, counted as that epoch.", "",
        "| claim | X | Y | seeds X / Y | censored X / Y | X: IQM [95 % CI] | Y: IQM [95 % CI] | "
        "X: mean [95 % CI] | Y: mean [95 % CI] | P(X earlier) [95 % CI] |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *_rows(results, "high"), "",
        *_groups_section(results, groups, epoch),
        *_provenance_section(results, groups),
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=Path, default=REPO / "docs" / "results" / "runs")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "results")
    p.add_argument("--reps", type=int, default=REPS,
                   help=f"bootstrap replications (default {REPS:,})")
    args = p.parse_args(argv)
    if not args.runs.is_dir():
        p.error(f"--runs {args.runs}: not a directory")
    if args.reps < 100:
        p.error(f"--reps must be at least 100, got {args.reps}")
    groups = load_groups(args.runs)
    command = " ".join(["python -m studies.claims", *(sys.argv[1:] if argv is None else argv)])
    text = report(evaluate(CLAIMS, groups, reps=args.reps), groups, command, reps=args.reps)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / OUTPUT).write_text(text)
    print(text, end="")
    print(f"wrote {args.out / OUTPUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
