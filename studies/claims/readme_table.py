"""The README's Results tables, from the claims' own results (claims.py): ours against the
authors' per task, simulator and method, and the paper's claim, HER-CS against HER. They sit
between two markers in README.md; `python -m studies.claims` rewrites them there, and a test
checks that the committed README holds what the committed runs give, so they cannot drift
from claims.md."""
from __future__ import annotations

from collections.abc import Sequence

from hercs.apps.plots import numbers
from hercs.apps.plots.series import marks_epsilon
from hercs.config.algorithm import default_energy_epsilon
from hercs.rl.methods import METHODS
from studies.claims.claim_runs import EPOCH, Group
from studies.claims.claim_statistics import Estimate
from studies.claims.claims import PICK_EPOCH, Claim, ClaimResult, verdict

BEGIN = ("<!-- results tables: written by `python -m studies.claims` "
         "(studies/claims/readme_table.py); do not edit by hand -->")
END = "<!-- end of the results tables -->"
OURS = "async"  # our runs' schedule in the tables: hercs' default
SIMULATOR = {"v1": "the authors' (v1)", "v4": "our default (v4)"}
TASK_ORDER = ("FetchPush", "FetchPickAndPlace")
THEIRS = "the authors'"


def _todays_setting(g: Group) -> str:
    """The `setting` of a group made with today's defaults on its simulator: v4's EBP runs
    carry ε 1e-3, which their names mark."""
    eps = default_energy_epsilon(g.env)
    return f"ε {eps:g}" if marks_epsilon(g.method, eps) else ""


def _defaults(g: Group) -> bool:
    return (g.schedule == OURS and g.precision == "fp32" and g.setting == _todays_setting(g))


def _read_where(c: Claim) -> bool:
    return c.epoch is None or c.epoch == PICK_EPOCH


def ours_against_authors(claims: Sequence[Claim]) -> list[Claim]:
    """Our runs with today's defaults against the authors' published ones, same method."""
    return [c for c in claims if _read_where(c) and c.y.schedule == "authors"
            and _defaults(c.x) and c.x.method == c.y.method and c.x.task == c.y.task]


def cs_against_her(claims: Sequence[Claim]) -> list[Claim]:
    """HER-CS against HER, ours with the defaults on each simulator and the authors'."""
    return [c for c in claims if _read_where(c) and (c.x.method, c.y.method) == ("her-cs", "her")
            and c.x.env == c.y.env and c.x.task == c.y.task
            and ((_defaults(c.x) and _defaults(c.y))
                 or c.x.schedule == c.y.schedule == "authors")]


def _order(r: ClaimResult) -> tuple[int, str, int]:
    """Task, then the authors' simulator before ours, then the paper's method order."""
    g = r.claim.x
    return (TASK_ORDER.index(g.task) if g.task in TASK_ORDER else len(TASK_ORDER), g.env,
            list(METHODS).index(g.method))


def selected(claims: Sequence[Claim]) -> list[Claim]:
    return [*ours_against_authors(claims), *cs_against_her(claims)]


def interval(e: Estimate) -> str:
    """A rate with its 95 % interval, as claims.md prints it: ".42 [.08, .80]"."""
    return f"{numbers.rate(e.value)} [{numbers.rate(e.low)}, {numbers.rate(e.high)}]"


def _task(r: ClaimResult) -> str:
    epoch = r.claim.epoch or EPOCH
    chosen = " (chosen after seeing the data)" if r.claim.post_hoc else ""
    return f"{r.claim.x.task}, epoch {epoch}{chosen}"


def _method(g: Group) -> str:
    eps = g.setting.removeprefix("ε ") if g.setting.startswith("ε ") else ""
    return METHODS[g.method].label + (f", ε = {numbers.power_of_ten(float(eps))}" if eps else "")


def _reading(r: ClaimResult, x: str, y: str) -> str:
    assert r.improvement is not None
    said = verdict(r.x.n, r.y.n, r.improvement[0])
    return said.replace("X ahead", f"{x} ahead").replace("Y ahead", f"{y} ahead")


def tables(results: Sequence[ClaimResult]) -> str:
    """The two tables (markdown), numbers printed as claims.md prints them."""
    lines = ["| task, read after | our simulator | method | ours: IQM [95 % CI] | the authors': "
             "IQM [95 % CI] | P(ours > the authors') [95 % CI] | runs ours / theirs | reading |",
             "|---|---|---|---|---|---|---|---|"]
    ours = set(ours_against_authors([r.claim for r in results]))
    for r in sorted((r for r in results if r.claim in ours), key=_order):
        head = f"| {_task(r)} | {SIMULATOR[r.x.group.env]} | {_method(r.x.group)} |"
        if r.x_stats is None or r.y_stats is None or r.improvement is None:
            lines.append(f"{head} no runs of ours yet | – | – | {r.x.n} / {r.y.n} | – |")
            continue
        lines.append(f"{head} {interval(r.x_stats.success_iqm)} | "
                     f"{interval(r.y_stats.success_iqm)} | "
                     f"{interval(r.improvement[0])} | {r.x.n} / {r.y.n} | "
                     f"{_reading(r, 'ours', THEIRS)} |")
    lines += ["", "| task, read after | runs | HER-CS: IQM [95 % CI] | HER: IQM [95 % CI] | "
              "P(HER-CS > HER) [95 % CI] | runs HER-CS / HER | reading |",
              "|---|---|---|---|---|---|---|"]
    cs = set(cs_against_her([r.claim for r in results]))
    for r in sorted((r for r in results if r.claim in cs),
                    key=lambda r: (*_order(r)[:2], r.claim.x.schedule != "authors")):
        whose = ("the authors' (v1)" if r.x.group.schedule == "authors"
                 else f"ours on {SIMULATOR[r.x.group.env]} simulator")
        if r.x_stats is None or r.y_stats is None or r.improvement is None:
            continue
        lines.append(f"| {_task(r)} | {whose} | {interval(r.x_stats.success_iqm)} | "
                     f"{interval(r.y_stats.success_iqm)} | {interval(r.improvement[0])} | "
                     f"{r.x.n} / {r.y.n} | {_reading(r, 'HER-CS', 'HER')} |")
    return "\n".join(lines) + "\n"


def block(results: Sequence[ClaimResult]) -> str:
    return f"{BEGIN}\n{tables(results)}{END}"


def replace_block(readme: str, results: Sequence[ClaimResult]) -> str:
    """`readme` with the text between BEGIN and END (markers included) written anew."""
    start, end = readme.find(BEGIN), readme.find(END)
    if start < 0 or end < start:
        raise ValueError(f"README.md: no results tables between {BEGIN!r} and {END!r}")
    return readme[:start] + block(results) + readme[end + len(END):]
