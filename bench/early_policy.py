"""What the early policies do on FetchPush-v1 and v4: how often they move the cube, and why.

    python -m bench.early_policy                      # committed runs + local logs: ~15 min
    python -m bench.early_policy --runs RUN_DIR ...   # logs of these runs (default: the local
                                                      # logs of the committed 5 + 5 HER-EBP-CS)

On v1 our HER-EBP-CS passes 0.5 some 17 epochs before v4 (docs/results/claims.md) and nothing
in the simulation's parameters explains it (docs/results/env_diff.md). Three measurements:

1. **Committed runs** (`docs/results/runs/*/metrics.csv`, no logs needed): the replay's
   `buffer_moved_share` — the share of stored episodes in which the object moved more than
   5 mm — at epochs 1, 5, 10, 15 and 20 of every FetchPush run that logs it, grouped by
   environment (version, weld torquescale) and method.
2. **The early policies' episodes** (the runs' MCAP logs, which stay on the machine that ran
   them): per block of one epoch's episodes (episode ids; asynchronous actors run a little
   ahead), the share in which the cube moved, the gripper's path length and net travel, its
   mean height above its start, and how far from the cube's start it ends.
3. **Open loop**: the logged action sequences of episodes 1,000–1,099 (epoch 5) of the first
   three runs of each environment, replayed without feedback in v1 and in v4 from the same
   reset seeds. If the simulators
   answered the same actions differently, the travel and the cube's motion would differ here;
   if they agree, the difference in part 2 is in what the policies learned. Needs v1 (`make
   mujoco-py`); left out, with the reason printed, where it is not installed.

Writes docs/results/early_policy.{json,md} (or --out DIR).
"""

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

from bench.common import REPO, git_commit
from hercs.api import read_metrics
from hercs.codec import msg_to_episode
from hercs.runlog import read_episodes

COMMITTED = REPO / "docs" / "results" / "runs"
LOCAL = REPO / "runs" / "sample_efficiency"
DEFAULT_RUNS = tuple(f"push-{v}her-ebp-cs-s{s}" for v in ("v1-", "") for s in range(1, 6))
SHARE_EPOCHS = (1, 5, 10, 15, 20)
BLOCKS = 12
MOVED_M = 0.005  # the replay's MOVED_THRESHOLD_M: an episode moved the cube when it went >5 mm
OPEN_LOOP_FIRST, OPEN_LOOP_COUNT = 1000, 100
FINDINGS = """\
Written from the tables above (2026-11-26); tests/bench/test_early_policy.py checks each claim
against docs/results/early_policy.json and the committed runs.

- **On v4 the early policies move the cube about a third as often, in every seed.** At epoch
  10 every committed v1 run (HER, HER-CS and HER-EBP-CS, 11 runs) has moved the cube
  in 13–18 % of its stored episodes and every v4 run (11 runs, the chaos soaks' and the
  torquescale-4 run included; all HER-EBP-CS: no v4 HER or HER-CS run logs the share yet) in
  5–10 %. The v4 share even falls after epoch 1 (random exploration moves the cube about as
  often on both, docs/results/env_diff.md), while v1's rises from epoch 5. HER-EBP-CS draws
  almost only such episodes on both (sampled share .92–.99), so on v4 it learns from 2–3×
  fewer of them for its first 20 epochs.
- **Because the v4 policies wander off.** Over epochs 3–11 the v4 policies' gripper path is
  1.0–1.1 m per episode against 0.85–0.93 on v1, it ends 0.36–0.37 m from the cube's start
  against 0.18–0.20, and it rides 10–13 cm above its start against 6–8: the v1 policies have
  begun to go to the cube, the v4 ones have not.
- **Not because the simulators answer actions differently.** The same logged action sequences
  replayed without feedback move the cube in the same episodes in both (equal shares in 5 of 6
  runs, .10 against .09 in the sixth) and carry the gripper 2–5 % farther along its path on
  v4 (3–10 % net: v4's mocap tracks a full action further per step, env_diff.md item 1),
  against 67 % more net travel in closed loop. So the difference is in what the two simulators' data
  teach the critic and actor in the first epochs, not in the arm's reach; and not in the
  weld's tilt either, since the torquescale-4 run (v1's tilt, env_diff.md item 2) behaves like
  v4 (5.9 % at epoch 10).
- **Next step, not taken here.** Train offline on one simulator's logged episodes of epochs
  0–5 and act in the other (or swap the cube's contact parameters only), to find which part of
  the data turns the policy away from the cube.
"""


def run_environment(config: dict) -> str:
    """`v1`, `v4` or `v4 torquescale N` from a run's resolved config."""
    task = config.get("task", {})
    version = task.get("env_version", "v4")
    scale = float(task.get("weld_torquescale", 1.0))
    return version if scale == 1.0 else f"{version} torquescale {scale:g}"


def read_config(run: Path) -> dict:
    return yaml.safe_load((run / "config.yaml").read_text()) or {}


# ------------------------------------------------------------------ 1. committed moved shares


def committed_moved_shares(folder: Path, epochs: Sequence[int] = SHARE_EPOCHS
                           ) -> list[dict[str, object]]:
    """One row per FetchPush run here whose metrics.csv has buffer_moved_share."""
    rows: list[dict[str, object]] = []
    for run in sorted(p for p in folder.iterdir() if (p / "metrics.csv").is_file()):
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
        rows.append({"run": run.name, "env": run_environment(config),
                     "method": config.get("run", {}).get("method", "?"), "share": share})
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
    training = read_config(run).get("training", {})
    per_epoch = int(training.get("cycles_per_epoch", 50)) * int(
        training.get("episodes_per_cycle", 4))
    out: dict[int, list[EpisodeFacts]] = {}
    actions: list[np.ndarray] = []
    for episode_id, msg in read_episodes(run):
        block = episode_id // per_epoch
        if block >= blocks and episode_id >= actions_of.stop:
            break
        episode = msg_to_episode(msg)
        if block < blocks:
            out.setdefault(block, []).append(episode_facts(episode.obs))
        if episode_id in actions_of:
            actions.append(episode.actions)
    return {b: mean_facts(f) for b, f in sorted(out.items())}, actions


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
    from hercs.envs import make_env, mujoco_py_problem
    from hercs.tasks import task_spec

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


def render(result: dict) -> str:
    lines = ["# What the early policies do on FetchPush-v1 and v4", "",
             f"`python -m bench.early_policy` — {result['when']}, commit {result['commit']}.",
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
              "| run | environment | moved | path | travel | height | end to cube |",
              "|---|---|---|---|---|---|---|"]
    for name, run in result["episodes"].items():
        late = [b for k, b in run["blocks"].items() if 3 <= int(k) <= 11]
        if not late:
            continue
        m = {k: np.mean([b[k] for b in late]) for k in ("moved_share", "path_m", "travel_m",
                                                       "height_m", "end_to_cube_m")}
        lines.append(f"| {name} | {run['env']} | {m['moved_share']:.3f} | {m['path_m']:.3f} | "
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
    lines += ["", "## What it shows", "", FINDINGS]
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
        LOCAL / name for name in DEFAULT_RUNS if (LOCAL / name / "episodes.mcap").exists()
        or any((LOCAL / name).glob("episodes.*.mcap"))]
    episodes: dict[str, dict[str, object]] = {}
    actions: dict[str, list[np.ndarray]] = {}
    for run in runs:
        env = run_environment(read_config(run))
        replay = (not args.no_open_loop and [r["env"] for r in episodes.values()].count(env)
                  < args.open_loop_runs)
        blocks, actions[run.name] = episode_blocks(run, actions_of=range(
            OPEN_LOOP_FIRST, OPEN_LOOP_FIRST + args.open_loop_count) if replay else range(0))
        episodes[run.name] = {"env": env, "blocks": {str(b): f for b, f in blocks.items()}}
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
    (args.out / "early_policy.md").write_text(render(result))
    print(render(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
