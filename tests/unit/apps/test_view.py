"""`hercs view`: a real MCAP log becomes a valid .rrd with the documented entity paths."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.apps.cli.main import main
from hercs.apps.views.episode_selection import parse_selection, select_episodes
from hercs.apps.views.view import headless_problem, read_run_log, run_view
from hercs.proto import hercs_pb2 as pb
from hercs.proto.schema import SCHEMA_VERSION
from hercs.rl.task_registry import task_spec
from hercs.run.rundir import RunDir
from hercs.run.runlog import EpisodeLogWriter
from hercs.wire.codec import array_to_msg, episode_to_msg
from tests.support import saved_run_config

RERUN = Path(sys.executable).parent / "rerun"


def _write_run(run_dir: Path, n: int = 12) -> None:
    spec = task_spec("push")
    rng = np.random.default_rng(0)
    with EpisodeLogWriter(RunDir(run_dir).episode_log, run="t", task="push") as writer:
        for i in range(n):
            if i == n // 2:
                writer.append_cluster_model(pb.ClusterModel(
                    schema_version=SCHEMA_VERSION, version=1,
                    centroids=array_to_msg(rng.uniform(-1, 1, (3, 3)).astype(np.float32)),
                    fitted_on=5, failures_seen=5))
            ep = random_episode(spec, rng, seq=i)
            writer.append_episode(episode_to_msg(ep, run="t", task="push"), episode_id=i)
    RunDir(run_dir).metrics.write_text(
        "epoch,env_steps,success_rate,env_steps_per_s,cluster_sizes,rejects\n"
        "1,300,0.1,400.5,3;4;5,\n"
        "2,600,0.2,410.0,4;4;6,\n")


def test_selection_parser() -> None:
    ids = list(range(10, 30))
    assert select_episodes("0:13", ids) == [10, 11, 12]
    assert select_episodes("12,15,99", ids) == [12, 15]
    assert select_episodes("last:3", ids) == [27, 28, 29]
    assert select_episodes("10:20:5,last:1", ids) == [10, 15, 29]
    assert select_episodes("25:", ids) == [25, 26, 27, 28, 29]
    assert select_episodes("all", ids) == ids
    assert select_episodes(None, ids) == ids  # fewer than an epoch's episodes
    assert select_episodes(None, list(range(2024)), last_epoch=200) == list(range(1824, 2024))
    spread = select_episodes("spread:200", list(range(2024)))
    assert len(spread) <= 201 and spread[0] == 0 and spread[-1] == 2023
    assert spread[:3] == [0, 11, 22]  # stride ceil(2024 / 200)
    assert parse_selection("last:20") == [("last", None, None, 20)]
    for bad in ("x", "1:2:0", "last:0", "-3", "1,,2", "1:2:3:4"):
        with pytest.raises(ValueError, match="--episodes"):
            parse_selection(bad)


def test_missing_path_exits_2(tmp_path: Path, capsys) -> None:
    assert main(["view", str(tmp_path / "nope"), "--save", str(tmp_path / "o.rrd")]) == 2
    assert "no such file or directory" in capsys.readouterr().err
    assert main(["view", str(tmp_path), "--save", str(tmp_path / "o.rrd")]) == 2
    assert "holds no episode log" in capsys.readouterr().err


def test_a_committed_run_without_its_log_says_what_it_keeps_and_what_to_run(
        tmp_path: Path, capsys) -> None:
    """A committed run keeps config, metrics and perhaps best.pt (issue 58): say so, and name
    `hercs plot` and `hercs eval`, rather than ask whether it is a run directory."""
    shipped = Path(__file__).resolve().parents[3] / "docs" / "results" / "runs" / "push-her-s1"
    assert main(["view", str(shipped), "--save", str(tmp_path / "o.rrd")]) == 2
    err = capsys.readouterr().err
    assert "is a run folder without its episode log" in err and "is it a run" not in err
    assert f"hercs plot {shipped} -o curve.png" in err and f"hercs eval {shipped}" in err


def test_bad_selection_exits_2(tmp_path: Path, capsys) -> None:
    _write_run(tmp_path, n=3)
    assert main(["view", str(tmp_path), "--episodes", "100:200",
                 "--save", str(tmp_path / "o.rrd")]) == 2
    assert "selects none of the 3 episodes" in capsys.readouterr().err


def test_view_saves_a_valid_rrd_with_the_documented_entities(tmp_path: Path) -> None:
    _write_run(tmp_path)
    out = tmp_path / "out.rrd"
    result = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "view", str(tmp_path),
                             "--save", str(out), "--episodes", "0,1,10:12"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert out.stat().st_size > 0
    verify = subprocess.run([str(RERUN), "rrd", "verify", str(out)], capture_output=True,
                            text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    printed = subprocess.run([str(RERUN), "rrd", "print", str(out)], capture_output=True,
                             text=True, timeout=120, check=True).stdout
    for entity in ("/world/episodes/000000/gripper", "/world/episodes/000011/object",
                   "/world/episodes/000010/goal", "/world/centroids", "/world/failed_goals",
                   "/episodes/success", "/log/episodes", "/curves/success_rate",
                   "/curves/env_steps_per_s", "/curves/cluster_sizes"):
        assert f" - {entity} - " in printed, entity
    assert "/world/episodes/000005/" not in printed  # not selected
    assert "/curves/rejects" not in printed  # an empty column


def test_without_a_display_the_viewer_is_not_spawned_and_the_user_is_told_why(
        tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    assert run_view(str(tmp_path)) == 2  # before reading anything: no hang, no spawn
    err = capsys.readouterr().err
    assert "no display here" in err and "--save" in err and "--web" in err
    assert headless_problem({"DISPLAY": ":0"}) is None
    assert headless_problem({"WAYLAND_DISPLAY": "wayland-0"}) is None


def test_default_view_draws_the_last_epoch_on_the_runs_clock(tmp_path: Path) -> None:
    """Without --episodes: the last epoch's episodes (cycles × episodes per cycle from the
    run's config.yaml), and the per-episode scalars also on the wall-clock `time` timeline."""
    _write_run(tmp_path)
    saved_run_config(tmp_path, ["training.cycles_per_epoch=2", "training.episodes_per_cycle=2"])
    out = tmp_path / "default.rrd"
    result = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "view", str(tmp_path),
                             "--save", str(out)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "drawing the last 4 episodes (one epoch, config.yaml)" in result.stderr
    assert "4 of 12 episodes" in result.stderr
    printed = subprocess.run([str(RERUN), "rrd", "print", "-vv", str(out)],
                             capture_output=True, text=True, timeout=120, check=True).stdout
    drawn = {int(m) for m in re.findall(r"/world/episodes/(\d{6})/gripper", printed)}
    assert drawn == {8, 9, 10, 11}
    # the episodes' insert times: the run's own clock (rrd print's column header)
    assert re.search(r"index_name: time\s", printed) and "Timestamp(ns)" in printed


def test_a_pruned_log_colours_its_first_episodes_by_its_replay_states_model(
        tmp_path: Path) -> None:
    """A bounded log whose older segments were deleted starts with a segment that begins
    with a replay state: its episodes get the clusters of the model that state holds, not -1
    as if no model had been fitted yet."""
    spec = task_spec("push")
    rng = np.random.default_rng(0)
    centroids = np.array([[-9, -9, -9], [9, 9, 9]], np.float32)  # every goal nearer centroid 0
    state = pb.ReplayState(schema_version=SCHEMA_VERSION, next_episode_id=40, first_held_id=30,
                           cluster_model=pb.ClusterModel(
                               schema_version=SCHEMA_VERSION, version=3,
                               centroids=array_to_msg(centroids), fitted_on=5,
                               failures_seen=5))
    with EpisodeLogWriter(tmp_path / "episodes.007.mcap", run="t", task="push") as writer:
        writer.append_replay_state(state)
        for i in range(40, 43):
            writer.append_episode(episode_to_msg(random_episode(spec, rng, seq=i), run="t",
                                                 task="push"), episode_id=i)
    run = read_run_log(tmp_path)
    assert [(e.episode_id, e.cluster) for e in run.episodes] == [(40, 0), (41, 0), (42, 0)]
    assert run.models == [], "the state's model is no new model on the timeline"
