"""docs/results/claims.md from the claims' results (studies/claims/claims.py): the tables of
IQM, mean and P(X > Y) per claim, the groups of runs behind them and where each run came from.
A pure function of the runs (fixed reps and RNG seed, no date), so a test checks the committed
file against them.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

from hercs.apps.plots import numbers
from studies.claims.claim_runs import (
    ASSUMED_KEYS,
    EPOCH,
    HIGH,
    LEGACY_LAG_CYCLES,
    MIN_SEEDS,
    THRESHOLD,
    Group,
    Run,
)
from studies.claims.claim_statistics import (
    REPS,
    RNG_SEED,
    Estimate,
)
from studies.claims.claims import (
    POST_HOC_EPOCHS,
    VERDICT_SEEDS,
    ClaimResult,
    Side,
    verdict,
)

# ---------------------------------------------------------------------------------- report

OUTPUT = "claims.md"

_EXACT_P_OF = {"success": 0, "epoch": 1, "high": 2}
"""Which of ClaimResult.exact_p each table reports."""

POST_HOC_LABEL = "(epoch chosen after seeing the data)"


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
        title = f"{r.claim.title} {POST_HOC_LABEL}" if r.claim.post_hoc else r.claim.title
        head = f"| {title} | {r.x.group.label} | {r.y.group.label} | {r.x.n} / {r.y.n} |"
        if which in ("epoch", "high"):
            cx, cy = (sum(s.censored_high if which == "high" else s.censored
                          for s in side.scores) for side in (r.x, r.y))
            head += f" {cx} / {cy} |"
        if (r.x_stats is None or r.y_stats is None or r.improvement is None or r.high is None
                or r.exact_p is None):
            lines.append(head + f" {_not_enough(r)} | – | – | – | – | – | – |")
            continue
        exact = f" {numbers.p_value(r.exact_p[_EXACT_P_OF[which]])} |"
        if which == "high":
            h = r.high
            cells = [_est(e, numbers.epoch) for e in (h.x_iqm, h.y_iqm, h.x_mean, h.y_mean)]
            poi = h.earlier
        elif which == "success":
            cells = [_est(st.success_iqm, numbers.rate) for st in (r.x_stats, r.y_stats)]
            cells += [_est(st.success_mean, numbers.rate) for st in (r.x_stats, r.y_stats)]
            poi = r.improvement[0]
        else:
            cells = [_est(st.epoch_iqm, numbers.epoch) for st in (r.x_stats, r.y_stats)]
            cells += [_est(st.epoch_mean, numbers.epoch) for st in (r.x_stats, r.y_stats)]
            poi = r.improvement[1]
        lines.append(head + " " + " | ".join(cells) + f" | {_est(poi, numbers.rate)} |" + exact
                     + f" {verdict(r.x.n, r.y.n, poi)} |")
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
                lines.append(f"| {label} | {s.run} | {numbers.rate(s.success)} | {at} | {high} |")
            for name in side.short:
                lines.append(f"| {label} | {name} | stopped before epoch {side.epoch}: "
                             "left out | – | – |")
    def no_claim(g: Group) -> str:
        return f"its group is in no claim ({g.task}, {g.label})"

    unused = sorted((run.name, no_claim(g)) for g, runs in groups.items()
                    if g not in seen and g.schedule != "authors" for run in runs)
    # a run dropped for a longer one of its seed is in no claim either way: say why that is
    # where its whole group is in none
    group_of = {run.name: g for g, runs in groups.items() for run in runs}
    unused += [(name, f"a longer run of its group and seed is counted: {kept}"
                if group_of.get(kept) in seen or kept not in group_of
                else no_claim(group_of[kept]))
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
             "ends): the hercs commit (+: with uncommitted changes; *started→finished* where "
             "a resumed run ended on another commit than it started on, the start from "
             "bench_done.json or, for the authors' code, config.yaml; *unknown→finished* where "
             "a resumed run was made before its start commit was recorded), the day it finished "
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
    notes = [(name, run.note) for name, run in sorted(by_name.items()) if run.note]
    if notes:
        lines += ["", "**Notes on runs**", "", *(f"- **{name}**: {note}" for name, note in notes)]
    return [*lines, ""]


def _runs(n: int) -> str:
    return f"{n} run{'' if n == 1 else 's'}"


def _at(side: Side) -> str:
    return f" (at epoch {side.epoch})" if side.epoch != EPOCH else ""


def _epochs(epochs: dict[int, str]) -> str:
    """"100 and 60"."""
    names = [str(e) for e in sorted(epochs, reverse=True)]
    return ", ".join(names[:-1]) + f" and {names[-1]}" if len(names) > 1 else names[0]


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
        f"lines, which are read at epochs {_epochs(POST_HOC_EPOCHS)}, each chosen after "
        "seeing the data (below).", "",
        "**Per run** (hercs/apps/plots/curves.py's rule, the Fig. 2 tables'): *success after epoch "
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
        f"cost being most of its time. **Exact p**: the two-sided p of P(X > Y) = .5 under "
        "the null that the two sides' runs are exchangeable, from every split of the pooled "
        "runs into sides of these sizes (`scipy.stats.permutation_test`, a Mann–Whitney test "
        "whose ties count half; studies/claims/claim_statistics.py `rank_test_p`). Unlike the "
        "bootstrap interval it does not undercover at small n, and it shows what a seed count "
        "can say at all: with 3 seeds a side no result gives less than .100, with 2 less than "
        f".333. A side with fewer than {MIN_SEEDS} seeds gets no numbers.", "",
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
        "can only resample the seeds there are, so an interval describes these seeds and is "
        "narrower than the uncertainty about the next one (a percentile bootstrap undercovers "
        "at such n). The **verdict** column applies one rule (studies/claims/claims.py "
        f"`verdict`): a line is a *lead* where a side has fewer than {VERDICT_SEEDS} runs or "
        "the interval of P holds .5; with "
        f"{VERDICT_SEEDS} runs or more a side and an interval that excludes .5, one side is "
        "*ahead in these seeds*, the most this file says of any line (the exact p says how "
        "far out the split lies). A lead is quoted with its P and interval; it rules no cause "
        "out and makes no two sides level. The runs also come from different machines and "
        "commits (the last "
        "section says which, per side), and one seed gives other numbers on another CPU "
        "(docs/DESIGN.md §10).", "",
        f"**Epochs chosen after seeing the data**, marked {POST_HOC_LABEL} on every line "
        "that reads one: "
        + "; ".join(POST_HOC_EPOCHS[e] for e in sorted(POST_HOC_EPOCHS, reverse=True))
        + ". A line at such an epoch is not a test planned before its runs.", "",
        "**Numbers** print by one rule, here and in fig2.md, asynchrony.md and `hercs plot`'s "
        "tables (hercs/apps/plots/numbers.py): the float each computes, correctly rounded, "
        "from one computation of each run's numbers (hercs/apps/plots/curves.py), so that "
        "pick-v1-her-cs-s4's 10-epoch mean at epoch 100, .685 in decimal and just below it "
        "as computed, prints .68 wherever it appears.", "",
        f"## Success after epoch {epoch}", "",
        "| claim | X | Y | seeds X / Y | X: IQM [95 % CI] | Y: IQM [95 % CI] | "
        "X: mean [95 % CI] | Y: mean [95 % CI] | P(X > Y) [95 % CI] | exact p | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        *_rows(results, "success"), "",
        f"## Epoch at which the 10-epoch mean first exceeds {THRESHOLD:g}", "",
        f"Censored: runs that never did by epoch {epoch}, counted as {epoch}. "
        "P(X earlier): the probability that a run of X gets there before a run of Y.", "",
        "| claim | X | Y | seeds X / Y | censored X / Y | X: IQM [95 % CI] | Y: IQM [95 % CI] | "
        "X: mean [95 % CI] | Y: mean [95 % CI] | P(X earlier) [95 % CI] | exact p | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        *_rows(results, "epoch"), "",
        f"## Epoch at which the 10-epoch mean first exceeds {HIGH:g}", "",
        f"As above, for {HIGH:g}: close to solved. Censored: runs that never did by their "
        "claim's epoch, counted as that epoch.", "",
        "| claim | X | Y | seeds X / Y | censored X / Y | X: IQM [95 % CI] | Y: IQM [95 % CI] | "
        "X: mean [95 % CI] | Y: mean [95 % CI] | P(X earlier) [95 % CI] | exact p | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        *_rows(results, "high"), "",
        *_groups_section(results, groups, epoch),
        *_provenance_section(results, groups),
    ]
    return "\n".join(lines)

