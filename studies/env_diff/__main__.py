"""`python -m studies.env_diff [--quick] [--variant NAME] [--out STEM]`: every comparison of the
package docstring, per task, into env_diff.{md,json}."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from hercs.rl.envs import mujoco_py_problem
from studies.env_diff import __doc__ as overview
from studies.env_diff.dynamics import (
    gripper_tracking,
    push_probe,
    slide_probe,
    step_replica_check,
)
from studies.env_diff.env_diff_report import CONCLUSION_HEADING, render_md, versions
from studies.env_diff.initial_states import initial_states
from studies.env_diff.models import all_field_rows, model_rows, option_rows
from studies.env_diff.rewards import reward_check
from studies.env_diff.rollouts import rollouts, switch_check, weld_sweep
from studies.env_diff.sim import TASKS, make_pair, make_v4_variant, variant_name, xml_variant_setup
from studies.study_output import REPO, git_commit, kept_findings, machine_identity


def compare_task(task: str, args: argparse.Namespace) -> dict[str, Any]:
    t0 = time.monotonic()
    s1, s4 = make_pair(task)
    others = []
    variants = {}
    for name in args.variant:
        sim, desc = make_v4_variant(task, name)
        others.append(sim)
        variants[name] = desc
    res: dict[str, Any] = {"env_ids": [s1.env.spec.id, s4.env.spec.id], "variants": variants}
    res["options"] = option_rows(s1, s4)
    res["params"] = model_rows(s1, s4)
    res["all_fields"] = all_field_rows(s1, s4)
    res["initial"] = initial_states(s1, s4, args.resets, args.still)
    res["initial"]["v4_xml"] = [xml_variant_setup(task, 4.0, False),
                                xml_variant_setup(task, 4.0, True)]
    sims = [s1, s4, *others]
    dyn: dict[str, Any] = {"step_replica_max_diff": step_replica_check(sims, 10)}
    dyn["gripper_tracking"] = gripper_tracking(sims)
    dyn["push_probe"] = push_probe(sims, range(args.probe_seeds), args.mags)
    dyn["slide_probe"] = slide_probe(sims, args.slide_cm)
    for kind, n in (("scripted", args.episodes), ("random", args.random_episodes)):
        for matched in (True, False):
            dyn[f"{kind}_{'matched' if matched else 'own'}"] = rollouts(
                sims, kind, n, matched, seed0=1000)
    res["dynamics"] = dyn
    res["weld_sweep"] = weld_sweep(s1, task, args.sweep, args.sweep_episodes)
    res["switches"] = switch_check(s4, task, args.switches, args.switch_episodes)
    res["reward"] = reward_check(s1, s4, 2000 if not args.quick else 200)
    res["seconds"] = round(time.monotonic() - t0, 1)
    for s in (s1, s4, *others):
        s.env.close()
    return res


DEFAULT_VARIANTS = ("torquescale=4", "torquescale=4+legacy-ccd")


def parse(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m studies.env_diff",
                                description=(overview or "").split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="CI: push, few resets and episodes")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "results" / "env_diff",
                   help="result stem: writes STEM.md and STEM.json")
    p.add_argument("--tasks", nargs="+", choices=TASKS, default=None)
    p.add_argument("--report-only", action="store_true",
                   help="rewrite STEM.md from STEM.json (no simulation)")
    p.add_argument("--resets", type=int, default=None, help="resets for the initial states")
    p.add_argument("--episodes", type=int, default=None, help="scripted-push episodes")
    p.add_argument("--random-episodes", type=int, default=None)
    p.add_argument("--variant", nargs="*", type=variant_name, default=None,
                   help="v4 model overrides to compare too: legacy-ccd, no-island, ls-tight, "
                   f"torquescale=X (default: {' '.join(DEFAULT_VARIANTS)}; none in --quick)")
    args = p.parse_args(argv)
    q = args.quick
    args.tasks = args.tasks or (["push"] if q else list(TASKS))
    args.resets = args.resets or (5 if q else 200)
    args.episodes = args.episodes or (2 if q else 40)
    args.random_episodes = args.random_episodes or (2 if q else 100)
    args.variant = (([] if q else list(DEFAULT_VARIANTS)) if args.variant is None
                    else args.variant)
    args.still = 2 if q else 20
    args.probe_seeds = 1 if q else 4
    args.mags = [1.0] if q else [0.25, 0.5, 1.0]
    args.slide_cm = [0.02] if q else [0.01, 0.02, 0.04]
    args.sweep = [1.0, 4.0] if q else [1.0, 2.0, 3.0, 4.0, 5.0, 8.0]
    args.sweep_episodes = 1 if q else 8
    args.switches = ["legacy-ccd"] if q else ["legacy-ccd", "no-island", "ls-tight"]
    args.switch_episodes = 1 if q else 10
    for k in ("resets", "episodes", "random_episodes"):
        if getattr(args, k) < 1:
            p.error(f"--{k.replace('_', '-')} must be >= 1")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse(argv)
    if args.report_only:
        result = json.loads(Path(f"{args.out}.json").read_text())
        report = Path(f"{args.out}.md")
        report.write_text(render_md(result, kept_findings(report, CONCLUSION_HEADING)))
        print(f"env_diff: rewrote {args.out}.md", file=sys.stderr)
        return 0
    problem = mujoco_py_problem()
    if problem is not None:
        print(f"env_diff: Fetch*-v1 needs mujoco-py and {problem}; `make mujoco-py` installs it",
              file=sys.stderr)
        return 2
    cmd = " ".join(["python", "-m", "studies.env_diff",
                    *(argv if argv is not None else sys.argv[1:])])
    result: dict[str, Any] = {
        "command": cmd, "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": git_commit(), "machine": machine_identity(), "versions": versions(),
        "quick": args.quick, "tasks": {}}
    for task in args.tasks:
        result["tasks"][task] = compare_task(task, args)
        print(f"env_diff: {task} done in {result['tasks'][task]['seconds']} s", file=sys.stderr)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Path(f"{args.out}.json").write_text(json.dumps(result, indent=1) + "\n")
    report = Path(f"{args.out}.md")  # its conclusion was written by hand: kept
    report.write_text(render_md(result, kept_findings(report, CONCLUSION_HEADING)))
    print(f"env_diff: wrote {args.out}.md and .json", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
