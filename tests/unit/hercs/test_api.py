"""The Python API (`hercs.load_policy`, `read_metrics`, `read_episodes`, `load_config`) on a
run directory made here: a config, a policy file written as the learner writes one, a
metrics.csv and an episode log in two segments. The real run is in
tests/integration/test_api_run.py."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import hercs
from bench.synthetic_episodes import random_episode
from hercs.actors.builder import ActorBuilder
from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.learner.checkpoint import save_policy
from hercs.rl.policy import Policy
from hercs.run.metrics import METRICS_COLUMNS
from hercs.run.rundir import RunDir, RunDirError
from hercs.run.runlog import EpisodeLog, segment_paths
from hercs.wire.codec import episode_to_msg, weights_to_msg

REPO = Path(__file__).resolve().parents[3]
RUN = "api-test"


def trained_like_policy(config: HercsConfig) -> Policy:
    """A policy with non-trivial weights and normaliser statistics (not the initial ones)."""
    spec = config.task.spec
    policy = Policy(spec=spec, config=config.ddpg, seed=7)
    rng = np.random.default_rng(3)
    policy.o_norm.update(rng.normal(0.5, 2.0, size=(200, spec.obs_dim)))
    policy.g_norm.update(rng.normal(1.0, 0.1, size=(200, spec.goal_dim)))
    policy.o_norm.recompute_stats()
    policy.g_norm.recompute_stats()
    policy.version = 40
    return policy


def weights_bytes(policy: Policy, epoch: int) -> bytes:
    w = policy.weights()
    return weights_to_msg(version=w.version, actor_params=w.actor, o_stats=w.o_stats,
                          g_stats=w.g_stats, epoch=epoch, evaluate=True).SerializeToString()


def logged_episode(spec, i: int):
    episode = random_episode(spec, np.random.default_rng(i), actor_id=f"actor-{i % 2}", seq=i)
    episode.success, episode.policy_version = i % 3 == 0, i // 2
    return episode_to_msg(episode, run=RUN, task=spec.name)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run_dir = tmp_path_factory.mktemp("runs") / RUN
    run_dir.mkdir()
    config = apply_overrides(HercsConfig(), ["task.name=reach", f"run.name={RUN}"])
    save_yaml(config, RunDir(run_dir).config)
    save_policy(RunDir(run_dir).checkpoints, "best.pt",
                weights=weights_bytes(trained_like_policy(config), epoch=2), epoch=2,
                success_rate=0.5, config=config.to_dict())
    with RunDir(run_dir).metrics.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=METRICS_COLUMNS)
        writer.writeheader()
        for epoch in (1, 2):
            writer.writerow({"epoch": epoch, "env_steps": 5000 * epoch,
                             "success_rate": 0.25 * epoch, "mean_final_distance": 0.1 / epoch,
                             "policy_lag_p50": "nan",
                             "cluster_sizes": "3;4", "cluster_share": "0.2500;0.7500",
                             "rejects": "duplicate:2;stale:1" if epoch == 2 else ""})
    spec = config.task.spec
    for ids in (range(0, 4), range(4, 7)):  # a replay restart between: two segments
        writer_, _ = EpisodeLog.open(run_dir, run=RUN, task=spec.name)
        for i in ids:
            writer_.append_episode(logged_episode(spec, i), episode_id=i)
        writer_.close()
    assert [p.name for p in segment_paths(run_dir)] == ["episodes.000.mcap", "episodes.mcap"]
    return run_dir


def observations(spec, n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"observation": rng.normal(0.5, 2.0, size=(n, spec.obs_dim)),
            "achieved_goal": rng.normal(1.0, 0.1, size=(n, spec.goal_dim)),
            "desired_goal": rng.normal(1.0, 0.1, size=(n, spec.goal_dim))}


# -- load_policy ------------------------------------------------------------------------------


def test_the_loaded_policy_acts_as_the_evaluator_acts_on_the_same_weights(run_dir: Path) -> None:
    """Against the evaluator's own path: the policy file's Weights bytes through
    hercs.actors.weights.WeightsDecoder into a Policy, acting with explore=False."""
    import torch

    policy = hercs.load_policy(run_dir)
    state = torch.load(RunDir(run_dir).checkpoint("best"), weights_only=False)
    config = HercsConfig.from_dict(state["config"])
    decoder = ActorBuilder(config).decoder()
    evaluator = Policy(spec=config.task.spec, config=config.ddpg, seed=0)
    evaluator.load(decoder.decode(decoder.parse(state["policy"])))

    obs = observations(policy.spec, 5)
    batched = policy.act(obs)
    assert batched.dtype == np.float32 and batched.shape == (5, policy.spec.action_dim)
    np.testing.assert_array_equal(
        batched, evaluator.act(obs["observation"], obs["desired_goal"], explore=False))
    for i in range(5):  # one at a time, as the evaluator acts
        single = policy.act({k: v[i] for k, v in obs.items()})
        assert single.shape == (policy.spec.action_dim,) and single.dtype == np.float32
        np.testing.assert_array_equal(
            single, evaluator.act(obs["observation"][i], obs["desired_goal"][i], explore=False))
        # a batch's matrix products may round the last bit differently
        np.testing.assert_allclose(single, batched[i], rtol=1e-5, atol=1e-7)
    assert (policy.epoch, policy.weights_version, policy.source.name) == (2, 40, "best.pt")
    assert np.abs(batched).max() <= policy.spec.max_action
    assert policy.config.run.name == RUN and "epoch=2" in repr(policy)


def test_act_is_deterministic_unless_asked_to_explore(run_dir: Path) -> None:
    policy = hercs.load_policy(run_dir, seed=1)
    obs = observations(policy.spec, 3)
    np.testing.assert_array_equal(policy.act(obs), policy.act(obs))
    explored = policy.act(obs, explore=True, rng=np.random.default_rng(5))
    assert not np.array_equal(explored, policy.act(obs))
    np.testing.assert_array_equal(
        explored, policy.act(obs, explore=True, rng=np.random.default_rng(5)))
    same_seed = hercs.load_policy(run_dir, seed=1)
    np.testing.assert_array_equal(policy.act(obs, explore=True),
                                  same_seed.act(obs, explore=True))


@pytest.mark.parametrize(
    ("observation", "message"),
    [
        ([1.0, 2.0], "act: got list, need the env's observation dict with keys "
                     "['observation', 'desired_goal']"),
        ({"observation": np.zeros(10)}, "act: the observation has no ['desired_goal']"),
        ({"observation": np.zeros(9), "desired_goal": np.zeros(3)},
         "act: observation['observation'] has shape (9,); task reach needs (10,) for one "
         "observation or (n, 10) for n"),
        ({"observation": np.zeros((2, 10)), "desired_goal": np.zeros(3)},
         "do not match: give both single (1-d) or both with n rows"),
        ({"observation": np.zeros((2, 10)), "desired_goal": np.zeros((3, 3))},
         "act: observation['observation'] (2, 10) and observation['desired_goal'] (3, 3)"),
    ],
    ids=["not-a-dict", "no-goal", "wrong-size", "single-and-batch", "batch-sizes"])
def test_act_refuses_an_observation_of_another_shape(run_dir: Path, observation: object,
                                                      message: str) -> None:
    policy = hercs.load_policy(run_dir)
    with pytest.raises(hercs.ObservationError) as err:
        policy.act(observation)  # type: ignore[arg-type]
    assert message in str(err.value)


def test_a_missing_checkpoint_is_named_with_those_that_exist(run_dir: Path) -> None:
    with pytest.raises(RunDirError) as err:
        hercs.load_policy(run_dir, "latest")
    assert str(err.value) == (
        f"{run_dir}: no checkpoint latest (learner.pt); {run_dir}/checkpoints holds best "
        "(best.pt): ask for one of those (best, latest, epoch-N or a .pt file's path)")


def test_a_checkpoint_given_by_path_loads(run_dir: Path, tmp_path: Path) -> None:
    copy = tmp_path / "mine.pt"
    copy.write_bytes((RunDir(run_dir).checkpoint("best")).read_bytes())
    policy = hercs.load_policy(tmp_path / "elsewhere", str(copy))
    assert policy.source == copy and policy.epoch == 2


# -- read_metrics -----------------------------------------------------------------------------


def test_read_metrics_parses_each_cell(run_dir: Path) -> None:
    metrics = hercs.read_metrics(run_dir)
    assert len(metrics) == 2 and metrics.columns == tuple(METRICS_COLUMNS)
    first, second = metrics
    assert first["epoch"] == 1 and isinstance(first["epoch"], int)
    assert second["env_steps"] == 10000 and second["success_rate"] == 0.5
    assert isinstance(first["policy_lag_p50"], float) and np.isnan(first["policy_lag_p50"])
    assert first["cluster_sizes"] == (3, 4) and first["cluster_share"] == (0.25, 0.75)
    assert first["rejects"] is None and second["rejects"] == {"duplicate": 2, "stale": 1}
    assert first["q_mean"] is None  # an empty cell
    np.testing.assert_array_equal(metrics.column("success_rate"), [0.25, 0.5])
    assert np.isnan(metrics.column("q_mean")).all()
    with pytest.raises(KeyError, match="no column 'succes'"):
        metrics.column("succes")
    direct = hercs.read_metrics(RunDir(run_dir).metrics)
    assert direct.columns == metrics.columns
    np.testing.assert_array_equal(direct.column("policy_lag_p50"), metrics.column("policy_lag_p50"))


def test_a_metrics_column_by_name_and_the_table_in_pandas(run_dir: Path) -> None:
    metrics = hercs.read_metrics(run_dir)
    epochs, success = metrics["epoch"], metrics["success_rate"]
    assert epochs.dtype == np.int64 and epochs.tolist() == [1, 2]
    assert success.dtype == np.float64 and success.tolist() == [0.25, 0.5]
    assert np.isnan(metrics["q_mean"]).all()  # empty cells
    assert metrics["cluster_sizes"] == [(3, 4), (3, 4)]  # not numbers: the parsed cells
    assert metrics["rejects"] == [None, {"duplicate": 2, "stale": 1}]
    with pytest.raises(KeyError, match="no column 'succes'; columns: \\['epoch'"):
        metrics["succes"]
    assert metrics[0] == metrics.rows[0] and metrics[-1]["epoch"] == 2  # rows by number
    assert metrics[:1] == metrics.rows[:1]
    with pytest.raises(TypeError, match="give a column name"):
        metrics[1.5]  # type: ignore[call-overload]
    frame = metrics.to_pandas()
    assert list(frame.columns) == list(METRICS_COLUMNS) and len(frame) == 2
    assert frame["success_rate"].tolist() == [0.25, 0.5]


COMMITTED_RUN = REPO / "docs" / "results" / "runs" / "push-her-cs-s1"


@pytest.mark.parametrize("pandas", ["installed", "missing"])
def test_read_metrics_by_name_in_a_users_interpreter(pandas: str) -> None:
    """A committed run's metrics.csv read as a user would, in a fresh interpreter; where
    pandas cannot be imported, to_pandas says what to install."""
    code = (("import sys; sys.modules['pandas'] = None\n" if pandas == "missing" else "")
            + "import json, hercs\n"
            f"m = hercs.read_metrics({str(COMMITTED_RUN)!r})\n"
            "out = {'success': m['success_rate'].tolist(), 'epochs': m['epoch'].tolist()}\n"
            "try:\n"
            "    out['frame'] = m.to_pandas()['success_rate'].tolist()\n"
            "except hercs.MissingPackage as exc:\n"
            "    out['frame'] = str(exc)\n"
            "print(json.dumps(out))\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    with RunDir(COMMITTED_RUN).metrics.open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert out["success"] == [float(r["success_rate"]) for r in rows]
    assert out["epochs"] == list(range(1, len(rows) + 1))
    assert out["frame"] == (out["success"] if pandas == "installed" else
                            "Metrics.to_pandas needs pandas, which this Python lacks: pip "
                            "install pandas (or take columns as arrays: "
                            "metrics['success_rate'])")


# -- read_episodes ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("selection", "ids"),
    [({}, list(range(7))), ({"ids": [5, 1, 99]}, [1, 5]), ({"last": 2}, [5, 6]),
     ({"ids": range(0, 7, 2), "last": 3}, [2, 4, 6]), ({"last": 0}, [])],
    ids=["all", "ids", "last", "ids-then-last", "last-0"])
def test_read_episodes_across_segments(run_dir: Path, selection: dict, ids: list[int]) -> None:
    episodes = list(hercs.read_episodes(run_dir, **selection))
    assert [e.id for e in episodes] == ids
    spec = hercs.load_config(run_dir).task.spec
    for episode in episodes:
        want = random_episode(spec, np.random.default_rng(episode.id))
        np.testing.assert_array_equal(episode.obs, want.obs)
        np.testing.assert_array_equal(episode.actions, want.actions)
        assert episode.obs.shape == (spec.episode_steps + 1, spec.obs_dim)
        assert episode.g.shape == (spec.episode_steps, spec.goal_dim)
        assert episode.obs.flags.writeable and episode.obs.dtype == np.float32
        assert (episode.success, episode.policy_version) == (episode.id % 3 == 0,
                                                             episode.id // 2)
        assert (episode.actor_id, episode.seq) == (f"actor-{episode.id % 2}", episode.id)
        assert (episode.run, episode.task) == (RUN, "reach")


def test_read_episodes_of_one_segment_file(run_dir: Path) -> None:
    assert [e.id for e in hercs.read_episodes(run_dir / "episodes.000.mcap")] == [0, 1, 2, 3]


# -- load_config ------------------------------------------------------------------------------


def test_load_config_from_defaults_a_run_or_a_file_with_overrides(run_dir: Path,
                                                                   tmp_path: Path) -> None:
    assert hercs.load_config() == HercsConfig()
    assert hercs.load_config(run_dir).run.name == RUN
    assert hercs.load_config(RunDir(run_dir).config).task.name == "reach"
    (tmp_path / "mine.yaml").write_text("ddpg:\n  lr_actor: 0.0005\n")
    config = hercs.load_config(tmp_path / "mine.yaml", ["task.name=push"])
    assert (config.ddpg.lr_actor, config.task.name, config.ddpg.gamma) == (0.0005, "push", 0.98)
    with pytest.raises(hercs.ConfigError, match=r"did you mean 'ddpg\.lr_actor'"):
        hercs.load_config(overrides=["ddpg.lr_actr=1e-3"])


@pytest.mark.parametrize(
    ("call", "message"),
    [(lambda d: hercs.read_metrics(d), "not a run directory: it has no config.yaml"),
     (lambda d: list(hercs.read_episodes(d)), "not a run directory: it has no config.yaml"),
     (lambda d: hercs.load_config(d), "not a run directory: it has no config.yaml"),
     (lambda d: hercs.load_policy(d), "not a run directory: it has no config.yaml"),
     (lambda d: hercs.load_policy(d / "nosuch"), "no such folder; give a run directory")],
    ids=["read_metrics", "read_episodes", "load_config", "load_policy", "load_policy-missing"])
def test_a_folder_that_is_not_a_run_says_what_it_lacks(tmp_path: Path, call, message: str
                                                       ) -> None:
    with pytest.raises(hercs.HercsError) as err:
        call(tmp_path)
    assert message in str(err.value)


def test_import_hercs_stays_light() -> None:
    """Every hercs process imports the package: the API defers torch, the log and the env."""
    code = ("import sys, hercs; print(sorted({m.split('.')[0] for m in sys.modules} & "
            "{'torch', 'mcap', 'gymnasium', 'zenoh', 'yaml'}))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                         text=True, timeout=60, check=True).stdout
    assert out.strip() == "[]"
