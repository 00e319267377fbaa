"""studies/authors_peer: the stand-ins their code runs on (one-rank MPI, the gym 0.17 calls over
a real gymnasium-robotics env), the run folder the claims read as a side of its own, the CLI's
refusals, and, where a checkout of the authors' repository is named by
HERCS_AUTHORS_CHECKOUT, a real run of their code stopped and resumed."""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from hercs.rl.envs import register_envs
from studies.authors_peer.old_gym import OldGymEnv, gym_module
from studies.authors_peer.peer_run import (
    KMEANS_N_INIT,
    PEER_SCHEDULE,
    PeerRun,
    precision_mismatch,
    recover_snapshot,
    resolved_precision,
    restore_cluster_centres,
    snapshot_epoch,
    write_config,
)
from studies.authors_peer.single_mpi import SUM, mpi4py_module
from studies.claims import claim_runs

REPO = Path(__file__).resolve().parents[3]
CHECKOUT = os.environ.get("HERCS_AUTHORS_CHECKOUT", "")


def test_one_rank_mpi_leaves_the_data_as_one_worker_would() -> None:
    world = mpi4py_module().MPI.COMM_WORLD
    assert (world.Get_rank(), world.Get_size()) == (0, 1)
    grads = np.arange(5, dtype=np.float32)
    out = np.zeros_like(grads)
    world.Allreduce(grads, out, op=SUM)
    np.testing.assert_array_equal(out, grads)
    params = grads.copy()
    world.Bcast(params, root=0)
    np.testing.assert_array_equal(params, grads)
    assert world.allreduce(0.35, op=SUM) == 0.35
    with pytest.raises(ValueError, match=r"only MPI\.SUM"):
        world.Allreduce(grads, out, op="max")
    with pytest.raises(ValueError, match="the only rank is 0"):
        world.Bcast(params, root=1)


def _make(name: str) -> object:
    import gymnasium as gym

    register_envs()
    return gym.make(name, disable_env_checker=True)


def test_old_gym_calls_over_a_real_fetch_env() -> None:
    """seed() takes effect at the next reset (the same start twice), reset() gives the
    observation dict, step() 4 values, and compute_reward is the env's, vectorised."""
    env = gym_module(_make).make("FetchPush-v4")
    assert isinstance(env, OldGymEnv) and env._max_episode_steps == 50
    env.seed(7)
    first = env.reset()
    env.seed(7)
    again = env.reset()
    np.testing.assert_array_equal(first["observation"], again["observation"])
    np.testing.assert_array_equal(first["desired_goal"], again["desired_goal"])
    other = env.reset()  # no new seed: the stream goes on
    assert not np.array_equal(other["desired_goal"], first["desired_goal"])
    obs, reward, done, info = env.step(env.action_space.sample())
    assert set(obs) == {"observation", "achieved_goal", "desired_goal"}
    assert isinstance(reward, float) and isinstance(done, bool) and "is_success" in info
    ag = np.stack([obs["achieved_goal"], obs["desired_goal"]])
    rewards = env.compute_reward(ag, np.stack([obs["desired_goal"]] * 2), None)
    assert rewards.shape == (2,) and rewards[1] == 0.0
    env.close()


def _peer_folder(root: Path, seed: int, success: list[float], precision: str = "fp32") -> Path:
    marked = "-tf32" if precision == "tf32" else ""
    run = PeerRun(checkout=root / "their-checkout", task="pick", seed=seed,
                  run_dir=root / f"pick-v1-authors-code{marked}-s{seed}", epochs=len(success))
    run.run_dir.mkdir(parents=True)
    args = argparse.Namespace(n_cycles=50, num_rollouts_per_mpi=4, n_batches=40, cuda=False,
                              seed=seed, env_name=run.env_id)
    write_config(run, args, commit="9c1bfa0", precision=precision)
    with (run.run_dir / "metrics.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["epoch", "success_rate"])
        writer.writerows([e, s] for e, s in enumerate(success, start=1))
    return run.run_dir


def test_restored_centres_keep_their_labels_and_later_refits_start_as_theirs() -> None:
    """A resumed peer run's k-means: the saved centres in their order, then every later refit
    exactly the uninterrupted run's (their unseeded k-means++ draws from NumPy's global stream,
    which a snapshot restores). Until 2026-11-29 later refits started from the saved centres."""
    from sklearn.cluster import KMeans

    rng = np.random.default_rng(7)
    before, after = rng.normal(size=(150, 3)), rng.normal(loc=2.0, size=(150, 3))
    straight = KMeans(n_clusters=8, n_init=KMEANS_N_INIT)
    np.random.seed(1)
    straight.fit(before)
    resumed = KMeans(n_clusters=8, n_init=KMEANS_N_INIT)
    restore_cluster_centres(resumed, straight.cluster_centers_)
    np.testing.assert_allclose(resumed.cluster_centers_, straight.cluster_centers_, atol=1e-12)
    np.testing.assert_array_equal(resumed.predict(before), straight.predict(before))
    assert resumed.get_params()["init"] == "k-means++"
    assert resumed.get_params()["n_init"] == KMEANS_N_INIT
    for model in (straight, resumed):
        np.random.seed(2)
        model.fit(after)
    np.testing.assert_allclose(resumed.cluster_centers_, straight.cluster_centers_, atol=1e-12)


def _snapshot(folder: Path, epoch: int) -> None:
    folder.mkdir(parents=True)
    (folder / "meta.json").write_text(json.dumps({"epoch": epoch}))
    (folder / "arrays.npz").write_bytes(b"arrays")


@pytest.mark.parametrize("stopped", ["writing the new one", "between the renames",
                                     "before dropping the old one"])
def test_a_stop_inside_a_snapshot_save_keeps_the_last_whole_snapshot(tmp_path: Path,
                                                                     stopped: str) -> None:
    """save_snapshot writes `.tmp`, renames the snapshot to `.old`, `.tmp` to the snapshot,
    then drops `.old`; wherever a stop comes, recovery leaves one whole snapshot (the newest
    whole one) and no leftovers, so the run resumes from it and its next save succeeds."""
    state = tmp_path / "peer_state"
    tmp, old = tmp_path / "peer_state.tmp", tmp_path / "peer_state.old"
    if stopped == "writing the new one":
        _snapshot(state, 7)
        _snapshot(tmp, 8)
        (tmp / "meta.json").unlink()  # half written
        expected = 7
    elif stopped == "between the renames":
        _snapshot(old, 7)
        _snapshot(tmp, 8)
        expected = 7  # .tmp may be whole, but nothing says so: its epoch is run again
    else:
        _snapshot(old, 7)
        _snapshot(state, 8)
        expected = 8
    recover_snapshot(state)
    assert snapshot_epoch(state) == expected
    assert sorted(p.name for p in tmp_path.iterdir()) == ["peer_state"]


def test_our_share_plan_by_hand_when_the_top_cluster_is_empty() -> None:
    """Seven clusters of 100 and an empty eighth: the reference rule splits the batch seven
    ways (36 each, 4 filled from the whole buffer), ours eight ways (32 each, 32 filled)."""
    from studies.authors_peer.sampler_check import labels_of, our_draws

    labels = labels_of([100] * 7 + [0])
    np.testing.assert_allclose(our_draws(labels, 8, "reference")[:7], 36 + 4 / 7)
    np.testing.assert_allclose(our_draws(labels, 8, "every-cluster")[:7], 32 + 32 / 7)
    assert our_draws(labels, 8, "every-cluster")[7] == 0


@pytest.mark.skipif(not CHECKOUT, reason="HERCS_AUTHORS_CHECKOUT names no checkout of the "
                    "authors' repository (it is never copied into this repository)")
def test_our_reference_share_rule_draws_what_their_sampler_draws() -> None:
    from studies.authors_peer.sampler_check import (
        labels_of,
        our_draws,
        their_draws,
        their_sampler,
    )

    sampler = their_sampler(Path(CHECKOUT))
    np.random.seed(3)
    for sizes in ([100] * 7 + [0], [5000, 10, 22, 294, 7000, 8, 6000, 80], [3, 0, 50, 0, 9, 1]):
        labels = labels_of(sizes)
        theirs = their_draws(sampler, labels, len(sizes), batches=400)
        # a mean of 400 draws of at most ~42 each: sd < 0.35; 2 draws is over 5 sd
        assert np.abs(our_draws(labels, len(sizes), "reference") - theirs).max() < 2.0, sizes


def test_acted_episodes_counts_moved_lifted_and_reached_by_hand(tmp_path: Path) -> None:
    """Four episodes a 'peer snapshot', two an epoch: one still, one pushed 1 cm, one lifted
    5 cm onto its goal, one trembling 1 mm; blocks of one epoch."""
    from studies.authors_peer.acted_episodes import main

    ag = np.zeros((4, 51, 3))
    ag[1, 30:, 0] = 0.01
    ag[2, 20:, 2] = 0.05
    ag[3, 10, 1] = 0.001
    goals = np.array([[1.0, 0, 0], [1.0, 0, 0], [0, 0, 0.05], [1.0, 0, 0]])
    state = tmp_path / "pick-v1-authors-code-s9" / "peer_state"
    state.mkdir(parents=True)
    np.savez(state / "arrays.npz", **{"buffer.ag": ag, "buffer.g": np.repeat(
        goals[:, None], 50, axis=1)})
    (state.parent / "config.yaml").write_text(yaml.safe_dump(
        {"training": {"cycles_per_epoch": 1, "episodes_per_cycle": 2, "epochs": 2}}))
    assert main([str(state), "--block", "1", "--out", str(tmp_path / "out")]) == 0
    summary = json.loads((tmp_path / "out" / "acted_episodes.json").read_text())
    assert summary["runs"]["pick-v1-authors-code-s9"] == [
        {"moved": 0.5, "lifted": 0.0, "success": 0.0},
        {"moved": 0.5, "lifted": 0.5, "success": 0.5}]


def test_a_peer_run_is_a_side_of_its_own_in_the_claims(tmp_path: Path) -> None:
    """Two peer seeds beside one of our HER-CS v1 runs: three groups (ours, the authors'
    published curves, their code on our v1), the peer's labelled as such, its start commit
    recorded."""
    for seed in (121, 123):
        _peer_folder(tmp_path, seed, [0.1 * seed % 1] * 50)
    ours = tmp_path / "pick-v1-her-cs-s1"
    ours.mkdir()
    (ours / "config.yaml").write_text(yaml.safe_dump(
        {"run": {"method": "her-cs", "seed": 1}, "task": {"name": "pick", "env_version": "v1"},
         "training": {"schedule": "lockstep"}}))
    (ours / "metrics.csv").write_text("epoch,success_rate\n" + "".join(
        f"{e},0.5\n" for e in range(1, 51)))
    groups = claim_runs.load_groups(tmp_path)
    peer = [g for g in groups if g.schedule == PEER_SCHEDULE]
    assert len(peer) == 1 and [r.seed for r in groups[peer[0]]] == [121, 123]
    assert peer[0].label == "HER-CS, authors' code on our v1"
    lockstep = [g for g in groups if g.schedule == "lockstep"]
    assert len(lockstep) == 1 and groups[lockstep[0]][0].name == "pick-v1-her-cs-s1"
    config = yaml.safe_load((tmp_path / "pick-v1-authors-code-s121" / "config.yaml").read_text())
    assert config["peer"]["commit"] == "9c1bfa0" and config["peer"]["started_commit"]


def test_precision_auto_is_their_torch_default_and_a_run_keeps_its_own(tmp_path: Path) -> None:
    """auto: TF32 on a GPU, fp32 on a CPU (torch 1.10.1's defaults); a run folder trained in
    one arithmetic is refused in the other, with both named and the way out."""
    assert resolved_precision("auto", cuda=False) == "fp32"
    assert resolved_precision("auto", cuda=True) == "tf32"
    assert resolved_precision("tf32", cuda=False) == "tf32"
    assert resolved_precision("fp32", cuda=True) == "fp32"
    with pytest.raises(ValueError, match="'bf16': must be one of auto, fp32, tf32"):
        resolved_precision("bf16", cuda=False)
    assert precision_mismatch(tmp_path / "none-yet", "tf32") is None
    fp32 = _peer_folder(tmp_path, 121, [0.1])
    tf32 = _peer_folder(tmp_path, 121, [0.1], precision="tf32")
    assert yaml.safe_load((fp32 / "config.yaml").read_text())["learner"]["precision"] == "fp32"
    config = yaml.safe_load((tf32 / "config.yaml").read_text())
    assert config["learner"]["precision"] == "tf32"
    assert "TF32 products emulated (hercs/learner/tf32.py)" in config["peer"]["adapted"]
    assert precision_mismatch(fp32, "fp32") is None and precision_mismatch(tf32, "tf32") is None
    why = precision_mismatch(fp32, "tf32")
    assert why is not None and "trained in fp32" in why and "continue in tf32" in why
    assert "--precision fp32" in why


def test_tf32_peer_runs_are_a_side_of_their_own(tmp_path: Path) -> None:
    for seed in (121, 123):
        _peer_folder(tmp_path, seed, [0.2] * 50)
        _peer_folder(tmp_path, seed, [0.4] * 50, precision="tf32")
    groups = claim_runs.load_groups(tmp_path)
    peer = {g.label: [r.name for r in groups[g]] for g in groups if g.schedule == PEER_SCHEDULE}
    assert peer == {
        "HER-CS, authors' code on our v1": ["pick-v1-authors-code-s121",
                                            "pick-v1-authors-code-s123"],
        "HER-CS, authors' code on our v1, tf32": ["pick-v1-authors-code-tf32-s121",
                                                  "pick-v1-authors-code-tf32-s123"]}


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "studies.authors_peer", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=120)


def test_a_folder_that_is_not_their_checkout_is_refused_up_front(tmp_path: Path) -> None:
    got = _cli("--checkout", str(tmp_path), "--run-dir", str(tmp_path / "runs"))
    assert got.returncode == 2
    assert "not a checkout of the authors' repository" in got.stderr and "train.py" in got.stderr
    assert not (tmp_path / "runs").exists(), "nothing is written before the run is accepted"


def test_an_unknown_precision_is_refused_by_name(tmp_path: Path) -> None:
    got = _cli("--checkout", str(tmp_path), "--precision", "fp16")
    assert got.returncode == 2 and "--precision: invalid choice: 'fp16'" in got.stderr


@pytest.mark.skipif(not CHECKOUT, reason="HERCS_AUTHORS_CHECKOUT names no checkout of "
                    "ngng9957/Clustering-based-Failed-Goal-Aware-Hindsight-Experience-Replay "
                    "(it is never copied into this repository)")
def test_their_code_runs_stops_and_resumes_to_the_same_numbers(tmp_path: Path) -> None:
    from tests.support import skip_without_mujoco_py

    skip_without_mujoco_py()
    straight = _cli("--checkout", CHECKOUT, "--quick", "--epochs", "3",
                    "--run-dir", str(tmp_path / "straight"))
    assert straight.returncode == 0, straight.stderr[-2000:]
    first = _cli("--checkout", CHECKOUT, "--quick", "--epochs", "2",
                 "--run-dir", str(tmp_path / "resumed"))
    assert first.returncode == 0, first.stderr[-2000:]
    name = "pick-v1-authors-code-s121"
    (tmp_path / "resumed" / name / "bench_done.json").unlink()  # as if stopped after epoch 2
    second = _cli("--checkout", CHECKOUT, "--quick", "--epochs", "3",
                  "--run-dir", str(tmp_path / "resumed"))
    assert second.returncode == 0 and "resumed after epoch 2" in second.stdout

    def rows(root: str) -> list[tuple[str, str]]:
        with (tmp_path / root / name / "metrics.csv").open() as f:
            return [(r["epoch"], r["success_rate"]) for r in csv.DictReader(f)]

    assert rows("resumed") == rows("straight") and len(rows("straight")) == 3
    done = json.loads((tmp_path / "resumed" / name / "bench_done.json").read_text())
    assert done["command"].startswith("-m studies.authors_peer --checkout "), done["command"]
    import torch

    def actor(root: str) -> dict[str, torch.Tensor]:
        nets = torch.load(tmp_path / root / name / "peer_state" / "nets.pt", weights_only=True)
        return nets["actor_network"]

    straight_actor, resumed_actor = actor("straight"), actor("resumed")
    assert all(torch.equal(straight_actor[k], resumed_actor[k]) for k in straight_actor), \
        "the resumed run trained the same policy as the uninterrupted one"


def test_fig2_draws_the_peer_as_the_authors_code_not_as_ours(tmp_path: Path) -> None:
    from studies.fig2.paper_figure import main as fig2

    runs = tmp_path / "runs"
    for seed in (121, 123):
        _peer_folder(runs, seed, [min(1.0, e / 60) for e in range(60)])
    assert fig2(["--runs", str(runs), "-o", str(tmp_path / "fig2.png"),
                 "--table", str(tmp_path / "fig2.md")]) == 0
    table = (tmp_path / "fig2.md").read_text()
    assert "| HER-CS, authors' simulator (v1) (authors' code) | 2 |" in table
    assert "authors-code" not in table and "(authors' code) (ours)" not in table


@pytest.mark.skipif(not CHECKOUT, reason="HERCS_AUTHORS_CHECKOUT names no checkout of "
                    "ngng9957/Clustering-based-Failed-Goal-Aware-Hindsight-Experience-Replay "
                    "(it is never copied into this repository)")
def test_their_code_in_emulated_tf32_trains_its_own_policy_resumes_and_keeps_to_it(
        tmp_path: Path) -> None:
    """On the CPU, the same seed in fp32 and in emulated TF32 (two quick epochs, 80 updates
    each) trains two different policies, each folder recording its arithmetic; a TF32 run
    stopped after epoch 1 and resumed (its snapshot loaded inside the emulation) trains the
    uninterrupted TF32 run's policy; and the fp32 folder is refused a TF32 continuation and
    left as it was."""
    from tests.support import skip_without_mujoco_py

    skip_without_mujoco_py()

    def peer(root: str, epochs: int, precision: str,
             *more: str) -> subprocess.CompletedProcess[str]:
        return _cli("--checkout", CHECKOUT, "--quick", "--epochs", str(epochs), "--device", "cpu",
                    "--run-dir", str(tmp_path / root), "--precision", precision, *more)

    fp32, tf32 = "pick-v1-authors-code-s121", "pick-v1-authors-code-tf32-s121"
    for got in (peer("straight", 2, "fp32"), peer("straight", 2, "tf32"),
                peer("resumed", 1, "tf32")):
        assert got.returncode == 0, got.stderr[-2000:]
    (tmp_path / "resumed" / tf32 / "bench_done.json").unlink()  # as if stopped after epoch 1
    second = peer("resumed", 2, "tf32")
    assert second.returncode == 0 and "resumed after epoch 1" in second.stdout, second.stderr
    import torch

    def actor(root: str, name: str) -> dict[str, torch.Tensor]:
        nets = torch.load(tmp_path / root / name / "peer_state" / "nets.pt", weights_only=True)
        return nets["actor_network"]

    straight, resumed = actor("straight", tf32), actor("resumed", tf32)
    assert all(torch.isfinite(w).all() for w in straight.values())
    assert all(torch.equal(straight[k], resumed[k]) for k in straight), \
        "the resumed TF32 run trained the uninterrupted one's policy"
    in_fp32 = actor("straight", fp32)
    assert any(not torch.equal(in_fp32[k], straight[k]) for k in in_fp32), "TF32 changed nothing"
    for name, precision in ((fp32, "fp32"), (tf32, "tf32")):
        folder = tmp_path / "straight" / name
        assert yaml.safe_load((folder / "config.yaml").read_text())["learner"]["precision"] \
            == precision
        done = json.loads((folder / "bench_done.json").read_text())
        assert (done["precision"], done["tf32_emulated"]) == (precision, precision == "tf32")
    folder = tmp_path / "straight" / fp32
    before = {f: (folder / f).read_bytes() for f in
              ("config.yaml", "metrics.csv", "bench_done.json", "peer_state/meta.json")}
    for epochs in (2, 3):  # finished, and asked for more
        refused = peer("straight", epochs, "tf32", "--name", fp32)
        assert refused.returncode == 2, refused.stdout
        assert "trained in fp32" in refused.stderr and "--precision fp32" in refused.stderr
    assert {f: (folder / f).read_bytes() for f in before} == before
