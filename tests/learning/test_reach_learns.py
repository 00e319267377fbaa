"""A whole distributed run (`hercs up`, every service as a real process over Zenoh on loopback)
must learn FetchReach, and its run directory must show the system's contracts: ratio held,
clusters fitted and balanced, weights reaching the actors, every acked episode logged once, no
process left behind. 10 cycles per epoch instead of 50; the paper's ratios (10 updates per episode).
"""

from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from hercs.run.rundir import RunDir
from hercs.run.runlog import read_cluster_models, read_episode_messages
from tests.support import free_endpoint

pytestmark = [pytest.mark.integration, pytest.mark.learning, pytest.mark.full]

EPOCHS = 6
CYCLES = 10
K = 4


def _hercs_pids(run_dir: Path) -> set[int]:
    """The hercs processes of the run in `run_dir` (its services read run_dir/config.yaml);
    other runs on the machine, a grid or another test's, are not this run's to leave."""
    pids = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        joined = b" ".join(cmdline)
        if (b"hercs.apps.cli" in joined and str(run_dir).encode() in joined
                and int(entry.name) != os.getpid()):
            pids.add(int(entry.name))
    return pids


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("runs")
    endpoint = free_endpoint()
    cmd = [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--method", "her-cs",
           "--actors", "2", "--epochs", str(EPOCHS), "--seed", "1", "--run", "reach-learns",
           "--run-dir", str(root), "--listen", endpoint,
           "--set", f"training.cycles_per_epoch={CYCLES}",
           "--set", f"cluster.k={K}", "--set", "cluster.fgb_size=40",
           "--set", "training.eval_episodes=20", "--set", "training.checkpoint_every=3"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    path = root / "reach-learns"
    logs = "\n".join(f"== {p.name}\n{p.read_text()[-2000:]}"
                     for p in sorted(RunDir(path).logs.glob("*.log"))) if path.exists() else ""
    assert proc.returncode == 0, (
        f"hercs up failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}\n{logs}")
    assert str(path) in proc.stdout, "hercs up prints where the run directory is"
    assert not _hercs_pids(path), "hercs up left service processes behind"
    return path


def rows(run_dir: Path) -> list[dict[str, str]]:
    with open(RunDir(run_dir).metrics) as f:
        return list(csv.DictReader(f))


def test_reach_reaches_90_percent_success(run_dir: Path) -> None:
    success = [float(r["success_rate"]) for r in rows(run_dir)]
    assert len(success) == EPOCHS
    assert max(success[-3:]) >= 0.9, f"success per epoch: {success}"


def test_rate_limiter_held_updates_per_episode(run_dir: Path) -> None:
    last = rows(run_dir)[-1]
    updates, episodes = int(last["updates"]), int(last["episodes"])
    assert updates == EPOCHS * CYCLES * 40
    # ρ = 10 updates per episode; the limiter's bound is E + n + ρ = 80 + 40 + 10 updates.
    assert abs(updates - 10 * episodes) <= 130 + 10 * 4, (updates, episodes)


def test_clusters_fitted_and_batches_balanced(run_dir: Path) -> None:
    table = rows(run_dir)
    assert int(table[-1]["cluster_model_version"]) >= 1
    models = list(read_cluster_models(run_dir))
    # The log holds every model the replay adopted, possibly one more after the last row.
    assert models and models[-1].version >= int(table[-1]["cluster_model_version"])
    assert [m.version for m in models] == list(range(1, len(models) + 1))
    last = table[-1]
    sizes = np.array([int(s) for s in last["cluster_sizes"].split(";")])
    share = np.array([float(s) for s in last["cluster_share"].split(";")])
    assert sizes.sum() == int(last["replay_size"]) // 50, "every stored episode is labelled"
    big = sizes >= 256 // K  # clusters under the small-cluster rule get more or less
    assert np.all(np.abs(share[big] - 1 / K) < 0.05), (sizes, share)


def test_every_logged_episode_is_unique_and_weights_reached_actors(run_dir: Path) -> None:
    seen = set()
    versions = []
    ids = []
    for episode_id, msg in read_episode_messages(run_dir):
        ids.append(episode_id)
        key = (msg.actor_id, msg.seq)
        assert key not in seen, f"episode {key} logged twice"
        seen.add(key)
        versions.append(msg.policy_version)
    assert ids == list(range(len(ids))), "episode ids are contiguous across the log"
    # The last row counts inserts when its epoch ended; actors keep inserting until stopped.
    assert len(seen) >= int(rows(run_dir)[-1]["episodes"])
    # wire ids are <ident>@<incarnation>: two actors, each one process for the whole run
    assert {actor.partition("@")[0] for actor, _ in seen} == {"actor-0", "actor-1"}
    assert len({actor for actor, _ in seen}) == 2, "no actor was restarted in a clean run"
    assert max(versions) >= EPOCHS * CYCLES - 5, "actors act with recent weights"
    saved = yaml.safe_load(RunDir(run_dir).config.read_text())
    assert saved["run"]["method"] == "her-cs" and saved["training"]["cycles_per_epoch"] == CYCLES


# -- the trained policy, used without any service (`hercs eval`) ----------------------------


@pytest.mark.parametrize("checkpoint", ["latest", "best", "epoch-3"])
def test_eval_reproduces_what_the_evaluator_measured(run_dir: Path, checkpoint: str) -> None:
    """The kept policy, on the goals the run's evaluator used for its epoch, scores exactly
    the success and final distance in metrics.csv."""
    from hercs.apps.evaluation.policy_eval import evaluate
    from hercs.run.policy_files import read_policy

    policy = read_policy(run_dir, checkpoint)
    recorded = {int(r["epoch"]): r for r in rows(run_dir)}
    expected_epoch = {"latest": EPOCHS, "epoch-3": 3,
                      "best": max(recorded, key=lambda e: (float(recorded[e]["success_rate"]),
                                                           -e))}[checkpoint]
    assert policy.epoch == expected_epoch
    summary = evaluate(policy, episodes=20)
    row = recorded[policy.epoch]
    assert summary.success_rate == pytest.approx(float(row["success_rate"]), abs=1e-9)
    assert summary.mean_final_distance == pytest.approx(float(row["mean_final_distance"]),
                                                        rel=1e-5)


def test_eval_records_a_video_of_every_step(run_dir: Path, tmp_path: Path) -> None:
    from hercs.apps.evaluation.policy_eval import EvalError, choose_gl

    try:
        choose_gl()
    except EvalError as exc:
        pytest.skip(f"no offscreen OpenGL on this machine: {exc}")
    import imageio_ffmpeg

    video = tmp_path / "policy.mp4"
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "eval", str(run_dir),
                           "--episodes", "2", "--video", str(video)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(video))
    # per episode a 1 s title (25 frames), then T + 1 = 51: the start and every step
    assert frames == 2 * (25 + 51)
    assert seconds == pytest.approx(frames / 25, abs=0.1)
    assert "152 frames at 25 fps" in done.stdout
    # each episode's frames carry its outcome: the bottom band's colour agrees with the
    # successes hercs eval counted (green for a success, red for a failure)
    reader = imageio_ffmpeg.read_frames(str(video))
    width, height = next(reader)["size"]
    decoded = [np.frombuffer(f, np.uint8).reshape(height, width, 3) for f in reader]
    successes = int(re.search(r"success [\d.]+ \((\d)/2\)", done.stdout).group(1))
    greens = 0
    for first in (25, 25 + 51 + 25):  # the first step frame of each episode
        band = decoded[first][-10:, 100:].reshape(-1, 3).astype(int).mean(axis=0)
        greens += bool(band[1] > band[0] + 40)  # green; red has its red channel above
        assert abs(band[1] - band[0]) > 40, f"band neither green nor red: {band}"
    assert greens == successes
