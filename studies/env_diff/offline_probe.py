"""Does the same exploration teach a different policy in FetchPush-v1 and v4? (offline probe)

    python -m studies.env_diff.offline_probe  # ~35 min beside two runs on 2 cores

Learns offline from the same random actions in each simulation, then evaluates in both. Writes
docs/results/offline_probe.{json,md} (or --out); why it is asked: docs/results/README.md."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any

import numpy as np

from hercs.config import HercsConfig, apply_overrides
from hercs.errors import ConfigError
from hercs.rl.policy import Policy, PolicyWeights
from hercs.wire.episode import EpisodeData
from studies.env_diff.early_policy import EpisodeFacts, episode_facts, mean_facts
from studies.study_output import REPO, add_out_option, git_commit, report_folder, write_report

SIMS = ("v1", "v4")
DATA_SEED = 555_000
"""Reset seeds of the data episodes (DATA_SEED + i) and the seed of their random actions."""
EVAL_SEED = 777_000
"""Reset seeds of the evaluation episodes: the same goals for every policy and simulation."""


def probe_config(version: str, seed: int) -> HercsConfig:
    return apply_overrides(HercsConfig(), [f"task.env_version={version}", "run.method=her",
                                           f"run.seed={seed}"])


def random_actions(episodes: int, steps: int, action_dim: int) -> list[np.ndarray]:
    rng = np.random.default_rng(DATA_SEED)
    return [rng.uniform(-1.0, 1.0, (steps, action_dim)) for _ in range(episodes)]


def collect(version: str, actions: Sequence[np.ndarray]) -> list[EpisodeData]:
    """Each action sequence stepped in `version` from reset(seed=DATA_SEED + i)."""
    from hercs.rl.envs import make_env

    spec = probe_config(version, 0).task.spec
    env = make_env(spec)
    out = []
    try:
        for i, seq in enumerate(actions):
            o, _ = env.reset(seed=DATA_SEED + i)
            obs, ag, g = [o["observation"]], [o["achieved_goal"]], []
            info: dict[str, Any] = {}
            for a in seq:
                g.append(o["desired_goal"])
                o, _, _, _, info = env.step(np.asarray(a, np.float64))
                obs.append(o["observation"])
                ag.append(o["achieved_goal"])
            out.append(EpisodeData(obs=np.asarray(obs, np.float32), ag=np.asarray(ag, np.float32),
                                   g=np.asarray(g, np.float32),
                                   actions=np.asarray(seq, np.float32), actor_id="probe",
                                   seq=i, success=bool(info.get("is_success", False))))
    finally:
        env.close()
    return out


def train(version: str, episodes: Sequence[EpisodeData], *, seed: int,
          cycles: int) -> PolicyWeights:
    """A DDPG learner trained offline on `episodes` for `cycles` cycles; its PolicyWeights."""
    from hercs.learner.ddpg import DDPGLearner
    from hercs.replay_service.builder import ReplayBuilder
    from hercs.rl.seeding import int_seed

    config = probe_config(version, seed)
    table = ReplayBuilder(config).table(rng=np.random.default_rng(int_seed(seed, "probe")))
    for ep in episodes:
        table.store_episode(ep)
    learner = DDPGLearner(spec=config.task.spec, config=config.ddpg, seed=seed, device="cpu")
    per_cycle = config.training.minibatches_per_cycle
    for _ in range(cycles):
        batch = table.draw(per_cycle, config.ddpg.batch_size)
        learner.set_normalizer_state(batch.o_stats, batch.g_stats)
        for minibatch in batch.minibatches:
            learner.train(minibatch)
        learner.update_targets()
    return learner.policy_weights(cycles)


def evaluate(weights: PolicyWeights, target: str, episodes: int) -> dict[str, float]:
    """Deterministic episodes of the policy in `target`: success and the early-policy facts."""
    from hercs.rl.envs import make_env

    config = probe_config(target, 0)
    policy = Policy(spec=config.task.spec, config=config.ddpg, seed=0)
    policy.load(weights)
    env = make_env(config.task.spec)
    facts: list[EpisodeFacts] = []
    success = []
    try:
        for i in range(episodes):
            o, _ = env.reset(seed=EVAL_SEED + i)
            obs, info = [o["observation"]], dict[str, Any]()
            for _ in range(config.task.spec.episode_steps):
                action = policy.act(o["observation"][None], o["desired_goal"][None],
                                    explore=False)[0]
                o, _, _, _, info = env.step(np.asarray(action, np.float64))
                obs.append(o["observation"])
            facts.append(episode_facts(np.asarray(obs)))
            success.append(float(info.get("is_success", 0.0)))
    finally:
        env.close()
    return mean_facts(facts) | {"success": round(float(np.mean(success)), 4)}


def run(*, sims: Sequence[str], episodes: int, cycles: int, seeds: Sequence[int],
        eval_episodes: int) -> dict[str, Any]:
    config = probe_config("v4", 0)
    spec = config.task.spec
    actions = random_actions(episodes, spec.episode_steps, spec.action_dim)
    result: dict[str, Any] = {"date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
                    "commit": git_commit(), "episodes": episodes, "cycles": cycles,
                    "updates": cycles * config.training.minibatches_per_cycle,
                    "seeds": list(seeds), "eval_episodes": eval_episodes, "data": {},
                    "policies": []}
    data: dict[str, list[EpisodeData]] = {}
    for sim in sims:
        start = time.perf_counter()
        data[sim] = collect(sim, actions)
        result["data"][sim] = mean_facts(episode_facts(e.obs) for e in data[sim]) | {
            "success": round(float(np.mean([e.success for e in data[sim]])), 4)}
        print(f"data {sim}: {result['data'][sim]} ({time.perf_counter() - start:.0f} s)",
              flush=True)
    for seed in seeds:
        for sim in sims:
            start = time.perf_counter()
            weights = train(sim, data[sim], seed=seed, cycles=cycles)
            acted_in = {target: evaluate(weights, target, eval_episodes) for target in sims}
            result["policies"].append({"trained_on": sim, "seed": seed, "acted_in": acted_in})
            print(f"seed {seed}, trained on {sim}: {acted_in} "
                  f"({time.perf_counter() - start:.0f} s)", flush=True)
    return result


FACTS = ("success", "moved_share", "travel_m", "height_m", "end_to_cube_m")


def render(result: dict[str, Any]) -> str:
    sims = list(result["data"])
    lines = ["# The same random exploration, learned from offline, in FetchPush-v1 and v4", "",
             f"`python -m studies.env_diff.offline_probe` — {result['date']}, commit "
             f"{result['commit']}. "
             f"{result['episodes']} episodes of uniform random actions (the same actions from "
             f"the same reset seeds in each simulation), loaded into the replay's core (HER, "
             f"future_p 0.8); a DDPG learner with the paper's settings trained on them for "
             f"{result['cycles']} cycles ({result['updates']} minibatches of 256, the target "
             f"update after every 40), nothing acting in between; learner seeds "
             f"{', '.join(map(str, result['seeds']))}. Each policy then acted deterministically "
             f"in {result['eval_episodes']} evaluation episodes (the same goals) in each "
             "simulation. *travel*: the gripper's start-to-end distance; *height*: its mean "
             "height above its start; *end to cube*: its final horizontal distance from the "
             "cube's start (m); *moved*: the share of episodes in which the cube moved > 5 mm.",
             "", "## The data", "",
             "| simulation | moved | travel | height | end to cube | success |",
             "|---|---|---|---|---|---|"]
    for sim in sims:
        d = result["data"][sim]
        lines.append(f"| {sim} | {d['moved_share']:.3f} | {d['travel_m']:.3f} | "
                     f"{d['height_m']:.3f} | {d['end_to_cube_m']:.3f} | {d['success']:.3f} |")
    lines += ["", "## The policies learned from it", "",
              "| trained on | seed | acted in | success | moved | travel | height | end to cube |",
              "|---|---|---|---|---|---|---|---|"]
    for row in result["policies"]:
        for target, f in row["acted_in"].items():
            lines.append(f"| {row['trained_on']} | {row['seed']} | {target} | {f['success']:.2f} | "
                         f"{f['moved_share']:.2f} | {f['travel_m']:.3f} | {f['height_m']:.3f} | "
                         f"{f['end_to_cube_m']:.3f} |")
    lines += ["", "## Mean over seeds", "",
              "| trained on | acted in | " + " | ".join(FACTS) + " |",
              "|---|---|" + "---|" * len(FACTS)]
    for trained in sims:
        for target in sims:
            rows = [r["acted_in"][target] for r in result["policies"] if r["trained_on"] == trained]
            lines.append(f"| {trained} | {target} | " + " | ".join(
                f"{np.mean([r[k] for r in rows]):.3f}" for k in FACTS) + " |")
    if result.get("findings"):
        lines += ["", "## What it shows", "", result["findings"]]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=600, help="data episodes per simulation")
    parser.add_argument("--cycles", type=int, default=150,
                        help="training cycles of 40 minibatches (50 = one epoch)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--sims", nargs="+", default=list(SIMS), choices=SIMS)
    add_out_option(parser, "offline_probe")
    parser.add_argument("--quick", action="store_true",
                        help="CI: 8 episodes, 2 cycles, one seed, 4 evaluation episodes")
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    if args.quick:
        args.episodes, args.cycles, args.seeds, args.eval_episodes = 8, 2, [1], 4
    for name in ("episodes", "cycles", "eval_episodes"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")
    try:
        result = run(sims=args.sims, episodes=args.episodes, cycles=args.cycles,
                     seeds=args.seeds, eval_episodes=args.eval_episodes)
    except ConfigError as err:  # v1 asked for where mujoco-py is not installed
        print(f"studies.env_diff.offline_probe: {err}", file=sys.stderr)
        return 2
    out = report_folder(args.out, args.quick, REPO)
    if out is not None and (out / "offline_probe.json").exists():
        # The reading is written by hand from the tables; a rerun keeps it to be re-read.
        result["findings"] = json.loads((out / "offline_probe.json").read_text()).get(
            "findings", "")
    text = render(result)
    print(text)
    write_report(out, "offline_probe", result, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
