"""TQC + HER-CS on FetchPush with Stable-Baselines3: rl-baselines3-zoo's FetchPush settings
(hyperparams/tqc.yml), with SB3's `HerReplayBuffer` replaced by hercs' `ClusterHerReplayBuffer`.

    pip install 'hercs[sb3]'
    python examples/sb3_tqc_her_cs_push.py --method her-cs --seed 1 --timesteps 1000000
    python examples/sb3_tqc_her_cs_push.py --method her ...    # the same draw without clusters

`--method her` draws episodes uniformly (the paper's HER), so the two runs differ only in the
draw. `--quick` runs a few hundred steps with small networks: a check that the script works,
not an experiment. A claim about learning needs several seeds a side.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
from sb3_contrib import TQC
from stable_baselines3.common.env_util import make_vec_env

from hercs.integrations.sb3 import ClusterHerReplayBuffer, success_rate
from hercs.rl.methods import METHODS

ZOO_FETCHPUSH = dict(
    buffer_size=1_000_000, batch_size=2048, gamma=0.95, learning_rate=1e-3, tau=0.05,
    policy_kwargs=dict(net_arch=[512, 512, 512], n_critics=2))
"""rl-baselines3-zoo's TQC settings for FetchPush (its HER: 'future', 4 sampled goals)."""

QUICK = dict(buffer_size=10_000, batch_size=64, gamma=0.95, learning_rate=1e-3, tau=0.05,
             learning_starts=100, policy_kwargs=dict(net_arch=[32], n_critics=1))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="FetchPush-v4", help="a goal-conditioned gymnasium id")
    parser.add_argument("--method", default="her-cs", choices=list(METHODS))
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--timesteps", type=int, default=1_000_000)
    parser.add_argument("--n-envs", type=int, default=1)
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--save", type=Path, help="save the model (and its replay buffer) here")
    parser.add_argument("--quick", action="store_true", help="a few hundred steps, small nets")
    args = parser.parse_args(argv)
    if args.env not in gym.registry:
        parser.error(f"--env: {args.env!r} is not a registered gymnasium id")
    settings = QUICK if args.quick else ZOO_FETCHPUSH
    timesteps = 300 if args.quick else args.timesteps
    env = make_vec_env(args.env, n_envs=args.n_envs, seed=args.seed)
    model = TQC("MultiInputPolicy", env, replay_buffer_class=ClusterHerReplayBuffer,
                replay_buffer_kwargs=dict(method=args.method, goal_selection_strategy="future",
                                          n_sampled_goal=4),
                seed=args.seed, verbose=0 if args.quick else 1, **settings)
    model.learn(timesteps)
    episodes = model.replay_buffer.episodes
    fits = episodes.model.version if episodes.model is not None else 0
    rate = success_rate(model, args.env, 5 if args.quick else args.eval_episodes,
                        seed=args.seed + 10_000)
    print(f"{args.env} {args.method} seed {args.seed}: {timesteps} steps, {episodes.episodes} "
          f"episodes in the buffer, {fits} k-means fits; success {rate:.2f}")
    if args.save is not None:
        model.save(args.save)
        model.save_replay_buffer(args.save.with_suffix(".buffer.pkl"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
