"""Trained in one simulation, acting in the other: is FetchPush-v4 harder to act in, or to learn?

    python -m studies.env_diff.cross_sim                 # the local HER-EBP-CS runs: ~1 h

Needs the runs' checkpoints (not committed) and, for v1, mujoco-py. Results accumulate in
docs/results/cross_sim.json (or --out DIR); cross_sim.md is rendered from it."""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from hercs.errors import ConfigError, HercsError
from hercs.run.policy_files import LoadedPolicy, read_policy
from hercs.run.rundir import RunDir
from studies.env_diff.early_policy import (
    episode_facts,
    open_loop_observations,
    read_config,
    run_environment,
)
from studies.study_output import REPO, git_commit

LOCAL = REPO / "runs" / "sample_efficiency"
DEFAULT_RUNS = (*(f"push-{v}her-ebp-cs-s{s}" for v in ("v1-", "") for s in range(1, 6)),
                "push-ts4-her-ebp-cs-s1")
DEFAULT_EPOCHS = (10, 20, 30, 40)
DEFAULT_TARGETS = ("v1", "v4", "v4-ts4")
SEED = 777_000
"""Env seeds of the evaluation episodes: SEED + i for parallel env i (none of a run's own
streams, which `hercs.rl.seeding` derives from the run seed)."""
PARALLEL_ENVS = 10
"""Envs stepped side by side (one batched policy call per step); episodes must divide by it."""
_TARGET = re.compile(r"^(v1|v4)(?:-ts(\d+(?:\.\d+)?))?$")


def parse_target(text: str) -> tuple[str, float]:
    """`v1`, `v4` or `v4-tsK` → (env_version, weld_torquescale)."""
    m = _TARGET.match(text)
    if not m or (m.group(1) == "v1" and m.group(2)):
        raise ConfigError(f"--targets: got {text!r}; expected v1, v4 or v4-tsK (v4 with the "
                          "mocap weld's torquescale K, e.g. v4-ts4)")
    scale = float(m.group(2)) if m.group(2) else 1.0
    if scale <= 0:
        raise ConfigError(f"--targets: {text!r}: the torquescale must be > 0")
    return m.group(1), scale


def on_target(policy: LoadedPolicy, target: str) -> LoadedPolicy:
    """The same weights, with the run's task moved to `target`'s simulation."""
    version, scale = parse_target(target)
    task = dataclasses.replace(policy.config.task, env_version=version, weld_torquescale=scale)
    return dataclasses.replace(policy, config=dataclasses.replace(policy.config, task=task))


@dataclasses.dataclass
class TargetResult:
    success: list[bool]
    moved: list[bool]
    goals: np.ndarray
    """(episodes, goal_dim): the desired goals, the same on every target for one seed."""

    def summary(self) -> dict[str, float | int]:
        return {"episodes": len(self.success),
                "success_rate": round(float(np.mean(self.success)), 4),
                "moved_share": round(float(np.mean(self.moved)), 4)}


def act_on(policy: LoadedPolicy, target: str, *, episodes: int, seed: int = SEED,
           parallel: int = PARALLEL_ENVS) -> TargetResult:
    """`episodes` deterministic episodes of `policy` in `target`, envs seeded seed, seed+1, …"""
    from hercs.actors.rollout import VectorRollout
    from hercs.rl.envs import make_env

    if episodes % parallel:
        raise ConfigError(f"--episodes: got {episodes}, must be a multiple of {parallel}")
    moved = on_target(policy, target)
    spec = moved.config.task.spec
    actor = moved.policy()
    vector = VectorRollout(spec=spec, envs=[make_env(spec) for _ in range(parallel)],
                           seeds=[seed + i for i in range(parallel)])
    success: list[bool] = []
    cube_moved: list[bool] = []
    goals: list[np.ndarray] = []
    try:
        for _ in range(episodes // parallel):
            for ep in vector.run_episodes(lambda o, g: actor.act(o, g, explore=False)):
                success.append(bool(ep.success))
                cube_moved.append(episode_facts(ep.obs).moved)
                goals.append(np.asarray(ep.g[0], np.float64))
    finally:
        vector.close()
    return TargetResult(success=success, moved=cube_moved, goals=np.stack(goals))


FETCH_OBS_FIELDS = (("grip_pos", 0, 3), ("object_pos", 3, 6), ("object_rel_pos", 6, 9),
                    ("gripper_state", 9, 11), ("object_rot", 11, 14), ("object_velp", 14, 17),
                    ("object_velr", 17, 20), ("grip_velp", 20, 23), ("gripper_vel", 23, 25))
"""The 25 dimensions of a Fetch object task's observation (gymnasium-robotics' `_get_obs`)."""
TABLE_TOP_Z = 0.4
"""Below this the cube (resting at z 0.425) has left the table."""
TURNED_RAD = 0.1


def random_action_stats(targets: Sequence[str], *, episodes: int, seed: int = SEED
                        ) -> dict[str, dict[str, object]]:
    """Per target: per-dimension std of the observation under the same uniform random
    actions from the same reset seeds, and the episodes that turned or dropped the cube."""
    from hercs.rl.envs import make_env
    from hercs.rl.task_registry import task_spec

    rng = np.random.default_rng(seed)
    push = task_spec("push")
    actions = [rng.uniform(-1.0, 1.0, (push.episode_steps, push.action_dim))
               for _ in range(episodes)]
    out: dict[str, dict[str, object]] = {}
    for target in targets:
        version, scale = parse_target(target)
        env = make_env(task_spec("push", version, scale))
        try:
            runs = open_loop_observations(env, actions, first_seed=seed)
        finally:
            env.close()
        o = np.stack(runs).astype(np.float64)  # (episodes, T + 1, 25)
        turned = np.abs(o[:, :, 11:14] - o[:, :1, 11:14]).max(axis=(1, 2)) > TURNED_RAD
        out[target] = {
            "std": [round(float(x), 5) for x in o.reshape(-1, o.shape[-1]).std(axis=0)],
            "turned": int(turned.sum()), "fell": int((o[:, :, 5].min(axis=1)
                                                       < TABLE_TOP_Z).sum()),
            "moved": int(sum(episode_facts(r).moved for r in o)), "episodes": episodes}
        print(f"random actions on {target}: turned {out[target]['turned']}, fell "
              f"{out[target]['fell']}, moved {out[target]['moved']} of {episodes}", flush=True)
    return out


# ------------------------------------------------------------------ report


def paired(result: dict, trained: str, epoch: int, a: str, b: str) -> list[float]:
    """Per run trained on `trained`: success on target `a` minus on target `b` at `epoch`."""
    out = []
    for run in result["runs"].values():
        cells = run["epochs"].get(str(epoch), {})
        if run["trained_on"] == trained and a in cells and b in cells:
            out.append(cells[a]["success_rate"] - cells[b]["success_rate"])
    return out


def render(result: dict) -> str:
    targets = result["targets"]
    lines = ["# Trained in one simulation, acting in the other (FetchPush, HER-EBP-CS)", "",
             f"`python -m studies.env_diff.cross_sim` — {result['when']}, commit "
             f"{result['commit']}, "
             f"{result['episodes']} episodes per (run, epoch, target), the same initial states "
             f"and goals on every target (env seeds {SEED}–{SEED + PARALLEL_ENVS - 1}).", ""]
    if result.get("left_out"):
        lines += [f"Left out: {result['left_out']}", ""]
    lines += ["## Success rate of each run's epoch-N policy, per target", "",
              "*trained on*: the simulation the run learned in; each cell is the success rate "
              "(share of the episodes that moved the cube in brackets).", "",
              "| run | trained on | epoch | " + " | ".join(targets) + " |",
              "|---|---|---|" + "---|" * len(targets)]
    for name, run in result["runs"].items():
        for epoch, cells in run["epochs"].items():
            row = " | ".join(
                f"{cells[t]['success_rate']:.2f} ({cells[t]['moved_share']:.2f})"
                if t in cells else "–" for t in targets)
            lines.append(f"| {name} | {run['trained_on']} | {epoch} | {row} |")
    lines += ["", "## Per simulation trained on: mean over runs [min, max]", "",
              "| trained on | epoch | runs | " + " | ".join(targets) + " |",
              "|---|---|---|" + "---|" * len(targets)]
    for trained, epoch, rates in group_means(result):
        row = " | ".join(f"{np.mean(r):.2f} [{min(r):.2f}, {max(r):.2f}]" if r else "–"
                         for r in rates)
        lines.append(f"| {trained} | {epoch} | {len(rates[0]) if rates else 0} | {row} |")
    if "v1" in targets and "v4" in targets:
        lines += ["", "## Paired: the same policy on v1 minus on v4", "",
                  "Per run, its success on v1 minus its success on v4 at that epoch; mean "
                  "over runs [min, max] and the runs with a positive difference.", "",
                  "| trained on | epoch | mean [min, max] | v1 better in |", "|---|---|---|---|"]
        for trained, epoch, _ in group_means(result):
            d = paired(result, trained, epoch, "v1", "v4")
            if d:
                lines.append(f"| {trained} | {epoch} | {np.mean(d):+.2f} [{min(d):+.2f}, "
                             f"{max(d):+.2f}] | {sum(x > 0 for x in d)} of {len(d)} |")
    stats = result.get("random_actions") or {}
    if stats:
        some = next(iter(stats.values()))
        lines += ["", "## What the networks see: the same random actions on each target", "",
                  f"{some['episodes']} episodes of uniform random actions, the same on every "
                  f"target, from reset seeds {SEED}, {SEED + 1}, …: per observation field the "
                  "standard deviation over all steps, per dimension (what the observation "
                  f"normaliser divides by); *turned*: episodes whose cube turned > {TURNED_RAD} "
                  "rad about some axis; *fell*: the cube left the table; *moved*: > 5 mm.", "",
                  "| field | " + " | ".join(stats) + " |", "|---|" + "---|" * len(stats)]
        for name, lo, hi in FETCH_OBS_FIELDS:
            cells = " | ".join(" ".join(f"{x:.4f}" for x in st["std"][lo:hi])
                               for st in stats.values())
            lines.append(f"| {name} | {cells} |")
        for key in ("moved", "turned", "fell"):
            lines.append(f"| *{key}* | " + " | ".join(f"{st[key]} of {st['episodes']}"
                                                     for st in stats.values()) + " |")
    if result.get("findings"):
        lines += ["", "## What it shows", "", result["findings"]]
    return "\n".join(lines) + "\n"


def group_means(result: dict) -> list[tuple[str, int, list[list[float]]]]:
    """(trained on, epoch, per target the runs' success rates), in a stable order."""
    groups: dict[tuple[str, int], list[list[float]]] = {}
    for run in result["runs"].values():
        for epoch, cells in run["epochs"].items():
            rates = groups.setdefault((run["trained_on"], int(epoch)),
                                      [[] for _ in result["targets"]])
            for i, t in enumerate(result["targets"]):
                if t in cells:
                    rates[i].append(cells[t]["success_rate"])
    return [(k[0], k[1], v) for k, v in sorted(groups.items())]


# ------------------------------------------------------------------ main


def run_bench(runs: Sequence[Path], epochs: Sequence[int], targets: Sequence[str],
              episodes: int, out: Path, random_episodes: int = 0) -> dict:
    """Part 1 for `runs` × `epochs` × `targets` (cells already in `out` are kept), then part 2
    with `random_episodes` episodes per target (0: left as it is)."""
    for t in targets:
        parse_target(t)  # a bad target fails before any work
    from hercs.rl.envs import mujoco_py_problem

    left_out = None
    if "v1" in targets and (why := mujoco_py_problem()) is not None:
        left_out = f"the v1 target (mujoco-py does not load here: {why}; `make mujoco-py`)"
        print(f"[skip] {left_out}", flush=True)
        targets = [t for t in targets if t != "v1"]
    path = out / "cross_sim.json"
    previous = json.loads(path.read_text()) if path.exists() else {}
    if previous.get("episodes") not in (None, episodes):
        raise ConfigError(f"--episodes {episodes}: {path} holds {previous['episodes']} per "
                          "cell; use the same, or another --out")
    result = {"when": previous.get("when", ""), "commit": previous.get("commit", ""),
              "episodes": episodes, "targets": list(targets),
              "left_out": left_out, "runs": previous.get("runs", {}),
              "random_actions": previous.get("random_actions", {}),
              "findings": previous.get("findings", "")}
    for run in runs:
        entry = result["runs"].setdefault(run.name, {
            "trained_on": run_environment(read_config(run)), "epochs": {}})
        for epoch in epochs:
            try:
                policy = read_policy(run, f"epoch-{epoch}")
            except HercsError as exc:  # a missing checkpoint is reported, not fatal
                print(f"[skip] {run.name} epoch {epoch}: {exc}", flush=True)
                continue
            cells = entry["epochs"].setdefault(str(epoch), {})
            for target in targets:
                if target in cells:
                    continue
                cells[target] = act_on(policy, target, episodes=episodes).summary()
                print(f"{run.name} epoch {epoch} on {target}: {cells[target]}", flush=True)
                save(result, path, new_results=True)  # resumable
    if set(result["random_actions"]) != set(targets) and random_episodes:
        result["random_actions"] = random_action_stats(targets, episodes=random_episodes)
        save(result, path, new_results=True)
    save(result, path, new_results=False)
    (out / "cross_sim.md").write_text(render(result))
    return result


def save(result: dict, path: Path, *, new_results: bool) -> None:
    """Write the JSON; with `new_results`, first stamp it with the time and commit."""
    if new_results:
        result["when"] = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
        result["commit"] = git_commit()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runs", nargs="*", type=Path, default=None,
                   help=f"run directories with epoch-N checkpoints (default: {LOCAL}'s "
                        f"{DEFAULT_RUNS[0]}, …, {DEFAULT_RUNS[-1]})")
    p.add_argument("--epochs", nargs="+", type=int, default=list(DEFAULT_EPOCHS))
    p.add_argument("--targets", nargs="+", default=list(DEFAULT_TARGETS),
                   help="v1, v4 or v4-tsK (default: %(default)s)")
    p.add_argument("--episodes", type=int, default=50,
                   help=f"per (run, epoch, target), a multiple of {PARALLEL_ENVS}")
    p.add_argument("--random-episodes", type=int, default=100,
                   help="part 2's random-action episodes per target (0: leave part 2 out)")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "results")
    args = p.parse_args(argv)
    runs = args.runs if args.runs is not None else [
        LOCAL / n for n in DEFAULT_RUNS if RunDir(LOCAL / n).checkpoints.is_dir()]
    try:
        result = run_bench(runs, args.epochs, args.targets, args.episodes, args.out,
                           args.random_episodes)
    except ConfigError as exc:
        p.error(str(exc))
    print(render(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
