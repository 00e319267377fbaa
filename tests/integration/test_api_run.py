"""The Python API on a real run: after a short `hercs up` on FetchReach, a fresh process that
imports only hercs and numpy checks that `hercs.load_policy(run_dir).act(obs)` chooses exactly
the evaluator's actions and reproduces its reported success and final distance, and that
`read_metrics`, `read_episodes` and `load_config` read the run back.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hercs.run.rundir import RunDir
from tests.support import free_endpoint

pytestmark = [pytest.mark.integration, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
EVAL_EPISODES = 2
RESETS = 6

# The user's side: hercs and numpy only (the env comes from hercs.rl.envs, as any
# gymnasium-robotics FetchReach-v4 would; the seed is the evaluator's, from the run's seed).
CHILD = r'''
import json, sys
import numpy as np
import hercs
from hercs.rl.envs import make_env
from hercs.rl.seeding import int_seed

run_dir, observations, out = sys.argv[1:4]
policy = hercs.load_policy(run_dir)
obs = dict(np.load(observations))
singles = np.stack([policy.act({k: v[i] for k, v in obs.items()})
                    for i in range(len(obs["observation"]))])
batched = policy.act(obs)

config, spec = policy.config, policy.spec
env = make_env(spec)
seed = int_seed(config.run.seed, "evaluator")
for _ in range((policy.epoch - 1) * config.training.eval_episodes):
    env.reset(seed=seed)
    seed = None
successes, distances = [], []
for _ in range(config.training.eval_episodes):
    o, _ = env.reset(seed=seed)
    seed = None
    for _ in range(spec.episode_steps):
        o, _, _, _, info = env.step(policy.act(o))
    successes.append(bool(info["is_success"]))
    distances.append(float(np.linalg.norm(o["achieved_goal"].astype(np.float32)
                                          - o["desired_goal"].astype(np.float32))))
np.savez(out + ".npz", singles=singles, batched=batched)
metrics = hercs.read_metrics(run_dir)
episodes = list(hercs.read_episodes(run_dir))
last = list(hercs.read_episodes(run_dir, last=2))
json.dump({"epoch": policy.epoch, "success_rate": sum(successes) / len(successes),
           "mean_final_distance": float(np.mean(distances)),
           "metrics_epochs": [row["epoch"] for row in metrics],
           "episodes": len(episodes), "episode_ids": [e.id for e in episodes],
           "last_ids": [e.id for e in last],
           "episode_shapes": [list(episodes[0].obs.shape), list(episodes[0].actions.shape)],
           "config_run": hercs.load_config(run_dir).run.name}, open(out + ".json", "w"))
'''


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("runs")
    cmd = [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--epochs", "1",
           "--actors", "1", "--run", "api", "--run-dir", str(root), "--listen",
           free_endpoint(), "--set", "training.cycles_per_epoch=2",
           "--set", f"training.eval_episodes={EVAL_EPISODES}"]
    done = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, f"hercs up failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    run_dir = root / "api"
    assert (RunDir(run_dir).checkpoint("best")).is_file()
    return run_dir


@pytest.fixture(scope="module")
def observations(run_dir: Path) -> dict[str, np.ndarray]:
    """Real FetchReach-v4 observations: resets with seeds 0..RESETS-1."""
    from hercs.config import load_yaml
    from hercs.rl.envs import make_env

    env = make_env(load_yaml(RunDir(run_dir).config).task.spec)
    resets = [env.reset(seed=seed)[0] for seed in range(RESETS)]
    env.close()
    return {key: np.stack([o[key] for o in resets]) for key in resets[0]}


@pytest.fixture(scope="module")
def user(run_dir: Path, observations: dict[str, np.ndarray],
         tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, dict[str, np.ndarray]]:
    """What the fresh process computed: (its JSON, its actions)."""
    folder = tmp_path_factory.mktemp("user")
    np.savez(folder / "obs.npz", **observations)
    done = subprocess.run([sys.executable, "-c", CHILD, str(run_dir), str(folder / "obs.npz"),
                           str(folder / "out")], cwd=folder, capture_output=True, text=True,
                          timeout=180, env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert done.returncode == 0, done.stderr[-3000:]
    with np.load(folder / "out.npz") as actions:
        return json.loads((folder / "out.json").read_text()), dict(actions)


@pytest.mark.full
def test_a_fresh_process_chooses_the_evaluators_actions(
        run_dir: Path, observations: dict[str, np.ndarray], user) -> None:
    import torch

    from hercs.actors.builder import ActorBuilder
    from hercs.config import HercsConfig
    from hercs.rl.policy import Policy
    from hercs.run.policy_files import read_policy

    state = torch.load(RunDir(run_dir).checkpoint("best"), weights_only=False)
    config = HercsConfig.from_dict(state["config"])
    decoder = ActorBuilder(config).decoder()
    evaluator = Policy(spec=config.task.spec, config=config.ddpg, seed=0)
    evaluator.load(decoder.decode(decoder.parse(state["policy"])))
    hercs_eval = read_policy(run_dir).policy()

    _, actions = user
    o, g = observations["observation"], observations["desired_goal"]
    expected = np.stack([evaluator.act(o[i], g[i], explore=False) for i in range(RESETS)])
    assert actions["singles"].dtype == np.float32
    assert actions["singles"].shape == (RESETS, config.task.spec.action_dim)
    np.testing.assert_array_equal(actions["singles"], expected)
    np.testing.assert_array_equal(
        actions["singles"],
        np.stack([hercs_eval.act(o[i], g[i], explore=False) for i in range(RESETS)]))
    np.testing.assert_array_equal(actions["batched"], evaluator.act(o, g, explore=False))
    assert not np.allclose(expected, expected[0]), "different observations, different actions"


def test_the_evaluators_episodes_replayed_with_it_score_what_metrics_csv_says(
        run_dir: Path, user) -> None:
    import hercs

    result, _ = user
    row = {r["epoch"]: r for r in hercs.read_metrics(run_dir)}[result["epoch"]]
    assert result["success_rate"] == row["success_rate"]
    assert result["mean_final_distance"] == pytest.approx(row["mean_final_distance"], rel=1e-6)


def test_the_run_reads_back_through_the_api(run_dir: Path, user) -> None:
    result, _ = user
    assert result["metrics_epochs"] == [1] and result["config_run"] == "api"
    assert result["episodes"] >= 8  # 2 cycles of 4 episodes
    assert result["episode_ids"] == list(range(result["episodes"]))
    assert result["last_ids"] == result["episode_ids"][-2:]
    assert result["episode_shapes"] == [[51, 10], [50, 4]]
