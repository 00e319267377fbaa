"""What the early policies do on FetchPush-v1 and v4: how often they move the cube, and why.

    python -m studies.env_diff.early_policy  # committed runs + local logs: ~15 min

Writes docs/results/early_policy.{json,md} (or --out DIR), whose sections 1–4 give each
measurement, keeping its hand-written findings; the question: docs/results/README.md."""

from __future__ import annotations

import argparse
import json
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import yaml

from hercs.api import read_metrics
from hercs.apps.plots.curves import EPSILON_UNMARKED, energy_epsilon, marks_epsilon
from hercs.config import EnergyConfig
from hercs.replay_service.energy import trajectory_energy
from hercs.run.rundir import RunDir
from hercs.run.runlog import read_episode_messages
from hercs.wire.codec import msg_to_episode
from studies.study_output import FINDINGS_HEADING, REPO, git_commit, kept_findings

COMMITTED = REPO / "docs" / "results" / "runs"
LOCAL = REPO / "runs" / "sample_efficiency"
DEFAULT_RUNS = (*(f"push-{v}her-ebp-cs-s{s}" for v in ("v1-", "") for s in range(1, 6)),
                "push-ts4-her-ebp-cs-s1", *(f"push-eps1e-3-her-ebp-cs-s{s}" for s in range(1, 4)),
                *(f"push-v1-{m}-s{s}" for m in ("her", "her-cs") for s in range(1, 7)),
                *(f"push-{m}-s{s}" for m in ("her", "her-cs") for s in range(1, 3)))
"""The HER-EBP-CS runs first: part 3 replays the first runs of each environment."""
SHARE_EPOCHS = (1, 5, 10, 15, 20)
SAMPLED_EPOCHS = 10
"""Epochs 1–10: the mean `sampled_moved_share` of each committed run in part 4."""
ENERGY = EnergyConfig()
"""EBP's energy with the defaults the committed runs used (clip 0.5, ε 1e-6)."""
ENERGY_BLOCKS = range(0, 6)
"""Blocks (epochs' worth of episodes) 0–5: part 4's early view of EBP's energies."""
BLOCKS = 12
MOVED_M = 0.005  # the replay's MOVED_THRESHOLD_M: an episode moved the cube when it went >5 mm
OPEN_LOOP_FIRST, OPEN_LOOP_COUNT = 1000, 100


def run_environment(config: dict) -> str:
    """`v1`, `v4` or `v4 torquescale N` from a run's resolved config."""
    task = config.get("task", {})
    version = task.get("env_version", "v4")
    scale = float(task.get("weld_torquescale", 1.0))
    return version if scale == 1.0 else f"{version} torquescale {scale:g}"


def run_method(config: dict) -> str:
    """The run's method, and EBP's ε where it is one a run's name marks (not 1e-6)."""
    method = str(config.get("run", {}).get("method", "?"))
    epsilon = energy_epsilon(config)
    return f"{method}, ε {epsilon:g}" if marks_epsilon(method, epsilon) else method


def read_config(run: Path) -> dict:
    return yaml.safe_load(RunDir(run).config.read_text()) or {}


# ------------------------------------------------------------------ 1. committed moved shares


def committed_moved_shares(folder: Path, epochs: Sequence[int] = SHARE_EPOCHS
                           ) -> list[dict[str, object]]:
    """One row per FetchPush run here whose metrics.csv has buffer_moved_share."""
    rows: list[dict[str, object]] = []
    for run in sorted(p for p in folder.iterdir() if RunDir(p).metrics.is_file()):
        config = read_config(run)
        if config.get("task", {}).get("name") != "push":
            continue
        metrics = read_metrics(run)
        if "buffer_moved_share" not in metrics.columns or not len(metrics):
            continue  # a run from before the column
        moved = metrics.column("buffer_moved_share")
        if np.isnan(moved[0]):
            continue
        share = {str(e): float(moved[e - 1]) for e in epochs if e <= len(moved)}
        sampled = (metrics.column("sampled_moved_share")[:SAMPLED_EPOCHS]
                   if "sampled_moved_share" in metrics.columns else np.array([np.nan]))
        rows.append({"run": run.name, "env": run_environment(config),
                     "method": run_method(config), "share": share,
                     "sampled_early": None if np.isnan(sampled).all()
                     else round(float(np.nanmean(sampled)), 4)})
    return rows


# ------------------------------------------------------------------ 2. the episodes


@dataclass
class EpisodeFacts:
    moved: bool
    path_m: float
    travel_m: float
    height_m: float
    end_to_cube_m: float


def episode_facts(obs: np.ndarray) -> EpisodeFacts:
    """From a Fetch object task's observations (T+1, 25): gripper at 0:3, cube at 3:6."""
    grip, cube = obs[:, 0:3].astype(np.float64), obs[:, 3:6].astype(np.float64)
    return EpisodeFacts(
        moved=bool(np.linalg.norm(cube - cube[:1], axis=-1).max() > MOVED_M),
        path_m=float(np.linalg.norm(np.diff(grip, axis=0), axis=-1).sum()),
        travel_m=float(np.linalg.norm(grip[-1] - grip[0])),
        height_m=float(grip[:, 2].mean() - grip[0, 2]),
        end_to_cube_m=float(np.linalg.norm(grip[-1, :2] - cube[0, :2])))


def mean_facts(facts: Iterable[EpisodeFacts]) -> dict[str, float]:
    """The share of episodes that moved the cube (`moved_share`) and the other facts' means."""
    items = list(facts)
    out = {("moved_share" if k == "moved" else k):
           round(float(np.mean([getattr(f, k) for f in items])), 4)
           for k in EpisodeFacts.__dataclass_fields__}
    return out | {"episodes": len(items)}


def episode_blocks(run: Path, blocks: int = BLOCKS, actions_of: range = range(0)
                   ) -> tuple[dict[int, dict[str, float]], list[np.ndarray]]:
    """Per block of one epoch's episode ids (0-based), the mean facts of its episodes; and,
    from the same pass over the log, the actions of the episodes whose ids are in
    `actions_of` (for the open-loop replay)."""
    config = read_config(run)
    training = config.get("training", {})
    epsilon = energy_epsilon(config)
    per_epoch = int(training.get("cycles_per_epoch", 50)) * int(
        training.get("episodes_per_cycle", 4))
    out: dict[int, list[EpisodeFacts]] = {}
    energies: dict[int, list[float]] = {}
    actions: list[np.ndarray] = []
    for episode_id, msg in read_episode_messages(run):
        block = episode_id // per_epoch
        if block >= blocks and episode_id >= actions_of.stop:
            break
        episode = msg_to_episode(msg)
        if block < blocks:
            out.setdefault(block, []).append(episode_facts(episode.obs))
            energies.setdefault(block, []).append(float(trajectory_energy(episode.ag, ENERGY)))
        if episode_id in actions_of:
            actions.append(episode.actions)
    return {b: mean_facts(f) | energy_view(f, energies[b], epsilon)
            for b, f in sorted(out.items())}, actions


def energy_view(facts: Sequence[EpisodeFacts], energy: Sequence[float],
                epsilon: float = EPSILON_UNMARKED) -> dict[str, float]:
    """What EBP makes of a block's episodes: the mean trajectory energy of those that left
    the cube still and of those that moved it, and the share of the block's draws the still
    ones would get from a sampler with p ∝ energy + ε (EBP's, leaving out EBP-CS's clusters;
    ε the run's `energy.epsilon`)."""
    e = np.asarray(energy, np.float64)
    still = ~np.array([f.moved for f in facts])
    weight = e + epsilon
    out = {"still_energy": float(e[still].mean()) if still.any() else 0.0,
            "moved_energy": float(e[~still].mean()) if (~still).any() else 0.0,
            "still_draw_share": float(weight[still].sum() / weight.sum())}
    return {k: _sig(v) for k, v in out.items()}


def _sig(x: float) -> float:
    return float(f"{x:.4g}")


# ------------------------------------------------------------------ 3. open loop


def open_loop_observations(env, action_sequences: Sequence[np.ndarray], first_seed: int = 1000
                           ) -> list[np.ndarray]:
    """Each sequence stepped without feedback from reset(seed=first_seed + i): its (T+1,
    obs_dim) observations."""
    out = []
    for i, actions in enumerate(action_sequences):
        obs, _ = env.reset(seed=first_seed + i)
        seen = [obs["observation"]]
        for action in actions:
            obs, *_ = env.step(np.asarray(action, dtype=np.float64))
            seen.append(obs["observation"])
        out.append(np.asarray(seen))
    return out


def replay_open_loop(env, action_sequences: Sequence[np.ndarray], first_seed: int = 1000
                     ) -> dict[str, float]:
    """Each sequence stepped without feedback from reset(seed=first_seed + i): mean facts."""
    return mean_facts(episode_facts(o) for o in
                      open_loop_observations(env, action_sequences, first_seed))


def open_loop(actions_by_run: dict[str, list[np.ndarray]]) -> dict[str, object]:
    from hercs.rl.envs import make_env, mujoco_py_problem
    from hercs.rl.task_registry import task_spec

    problem = mujoco_py_problem()
    if problem:
        return {"skipped": f"FetchPush-v1 cannot be made here: {problem}"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        envs = {v: make_env(task_spec("push", v)) for v in ("v1", "v4")}
    out: dict[str, object] = {}
    for name, actions in actions_by_run.items():
        out[name] = {v: replay_open_loop(env, actions) for v, env in envs.items()}
        print(f"open loop {name}: {out[name]}", flush=True)
    return out


# ------------------------------------------------------------------ report


def render(findings: str, result: dict) -> str:
    lines = ["# What the early policies do on FetchPush-v1 and v4", "",
             f"`python -m studies.env_diff.early_policy` — {result['when']}, commit "
             f"{result['commit']}.",
             "", "## 1. How often the stored episodes moved the cube (committed runs)", "",
             "The replay's `buffer_moved_share` (the cube moved > 5 mm; all episodes stored so "
             "far), from each committed FetchPush run's metrics.csv.", "",
             "| run | environment | method | " + " | ".join(f"epoch {e}" for e in SHARE_EPOCHS)
             + " |", "|---|---|---|" + "---|" * len(SHARE_EPOCHS)]
    for r in result["committed"]:
        cells = " | ".join(f"{r['share'][str(e)]:.3f}" if str(e) in r["share"] else "–"
                           for e in SHARE_EPOCHS)
        lines.append(f"| {r['run']} | {r['env']} | {r['method']} | {cells} |")
    lines += ["", "## 2. The early policies' episodes (local logs)", "",
              "Per block of one epoch's episode ids: *moved*, the share in which the cube moved "
              "> 5 mm; *path*, the gripper's path length; *travel*, its start-to-end distance; "
              "*height*, its mean height above its start; *end to cube*, its final horizontal "
              "distance from the cube's start (m). Blocks 3–11, mean of the run's blocks:", "",
              "| run | environment | method | moved | path | travel | height | end to cube |",
              "|---|---|---|---|---|---|---|---|"]
    for name, run in result["episodes"].items():
        late = [b for k, b in run["blocks"].items() if 3 <= int(k) <= 11]
        if not late:
            continue
        m = {k: np.mean([b[k] for b in late]) for k in ("moved_share", "path_m", "travel_m",
                                                       "height_m", "end_to_cube_m")}
        lines.append(f"| {name} | {run['env']} | {run.get('method', '?')} | "
                     f"{m['moved_share']:.3f} | {m['path_m']:.3f} | "
                     f"{m['travel_m']:.3f} | {m['height_m']:.3f} | {m['end_to_cube_m']:.3f} |")
    lines += ["", "## 3. The same actions without feedback, in v1 and in v4", ""]
    loop = result["open_loop"]
    if "skipped" in loop:
        lines.append(f"Left out: {loop['skipped']}")
    else:
        lines += [f"Episodes {OPEN_LOOP_FIRST}– of each run (its epoch 5; counts in the json), "
                  "their logged actions stepped from reset seeds 1000, 1001, "
                  "… in each simulator:", "",
                  "| actions of | stepped in | moved | path | travel | height | end to cube |",
                  "|---|---|---|---|---|---|---|"]
        for name, per_env in loop.items():
            for env, f in per_env.items():
                lines.append(f"| {name} | {env} | {f['moved_share']:.3f} | {f['path_m']:.3f} | "
                             f"{f['travel_m']:.3f} | {f['height_m']:.3f} | "
                             f"{f['end_to_cube_m']:.3f} |")
    lines += ["", "## 4. What EBP makes of the episodes that leave the cube still", "",
              "Blocks 0–5 of each run's log (mean of the blocks): *still*, the share of "
              "episodes in which the cube moved ≤ 5 mm; their mean trajectory energy "
              "(hercs.replay_service.energy, the runs' settings) and that of the others; "
              "*still draws*, the share of draws the still episodes would get from p ∝ "
              "energy + ε (EBP's rule without EBP-CS's clusters); *sampled moved*, the run's "
              f"committed `sampled_moved_share`, mean of epochs 1–{SAMPLED_EPOCHS}.", "",
              "| run | environment | method | still | still energy | moved energy | "
              "still draws | sampled moved |", "|---|---|---|---|---|---|---|---|"]
    sampled = {r["run"]: r.get("sampled_early") for r in result["committed"]}
    for name, run in result["episodes"].items():
        early = [b for k, b in run["blocks"].items() if int(k) in ENERGY_BLOCKS
                 and "still_energy" in b]
        if not early or "ebp" not in str(run.get("method")):
            continue
        m = {k: np.mean([b[k] for b in early]) for k in ("moved_share", "still_energy",
                                                        "moved_energy", "still_draw_share")}
        s = sampled.get(name)
        lines.append(f"| {name} | {run['env']} | {run['method']} | {1 - m['moved_share']:.3f} | "
                     f"{m['still_energy']:.2e} | {m['moved_energy']:.3f} | "
                     f"{m['still_draw_share']:.3f} | {'–' if s is None else f'{s:.3f}'} |")
    if findings:
        lines += ["", FINDINGS_HEADING, "", findings.rstrip("\n")]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runs", nargs="*", type=Path, default=None,
                   help="run directories with episode logs (default: the local logs of "
                        f"{', '.join(DEFAULT_RUNS[:2])}, …)")
    p.add_argument("--committed", type=Path, default=COMMITTED)
    p.add_argument("--no-open-loop", action="store_true", help="leave part 3 out")
    p.add_argument("--open-loop-runs", type=int, default=3,
                   help="replay the actions of the first N runs of each environment")
    p.add_argument("--open-loop-count", type=int, default=OPEN_LOOP_COUNT,
                   help="episodes per run replayed open loop, from id "
                        f"{OPEN_LOOP_FIRST}")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "results")
    args = p.parse_args(argv)

    runs = args.runs if args.runs is not None else [
        LOCAL / name for name in DEFAULT_RUNS if RunDir(LOCAL / name).episode_log.exists()
        or any((LOCAL / name).glob("episodes.*.mcap"))]
    episodes: dict[str, dict[str, object]] = {}
    actions: dict[str, list[np.ndarray]] = {}
    for run in runs:
        env = run_environment(read_config(run))
        replay = (not args.no_open_loop and [r["env"] for r in episodes.values()].count(env)
                  < args.open_loop_runs)
        blocks, actions[run.name] = episode_blocks(run, actions_of=range(
            OPEN_LOOP_FIRST, OPEN_LOOP_FIRST + args.open_loop_count) if replay else range(0))
        episodes[run.name] = {"env": env, "method": run_method(read_config(run)),
                              "blocks": {str(b): f for b, f in blocks.items()}}
        print(f"episodes {run.name}: {len(blocks)} blocks", flush=True)
    actions = {name: a for name, a in actions.items() if a}
    loop = ({"skipped": "--no-open-loop"} if args.no_open_loop or not actions
            else open_loop(actions))
    committed = committed_moved_shares(args.committed)
    result = {"when": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "commit": git_commit(),
              "committed": committed,
              "episodes": episodes, "open_loop": loop}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "early_policy.json").write_text(json.dumps(result, indent=1) + "\n")
    report = args.out / "early_policy.md"
    text = render(kept_findings(report), result)  # the findings were written by hand: kept
    report.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
