"""The live view's core (`LiveRecorder`) logging to real Rerun recordings: the same entities,
timelines and values as `hercs view` of the same run; headers checked; failed goals bounded;
a viewer that goes away is reported once while the .rrd file keeps being written."""

from __future__ import annotations

import dataclasses
import logging
import signal
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from bench.synthetic_episodes import random_episode
from hercs.apps.cli.main import main
from hercs.apps.launch.router import free_port
from hercs.apps.views.live_recorder import LiveRecorder, header_outcome
from hercs.apps.views.live_sinks import ViewerHealth
from hercs.errors import ConfigError, InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.proto.schema import SCHEMA_VERSION
from hercs.rl.cluster_model import assign_clusters
from hercs.rl.task_registry import task_spec
from hercs.run.rundir import RunDir
from hercs.run.runlog import EpisodeLogWriter
from hercs.wire.codec import array_to_msg, episode_to_msg
from hercs.wire.episode import EpisodeData
from tests.support import rerun_viewer

RERUN = Path(sys.executable).parent / "rerun"
SPEC = task_spec("push")
_BOOKKEEPING = {"rerun.controls.RowId", "log_time", "log_tick"}
_OFFLINE_ONLY = {"time"}  # the log's insert times; live, rerun's own log_time is that clock


def rrd_rows(path: Path) -> dict[str, list[dict]]:
    """Every logged row of a recording by entity path: its timelines and components (without
    rerun's own row ids and log times), in logging order."""
    rows: dict[str, list[dict]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        names = [n for n in batch.schema.names if n not in _BOOKKEEPING | _OFFLINE_ONLY]
        rows[chunk.entity_path] += batch.select(names).to_pylist()
    return rows


def verify(path: Path) -> str:
    """`rerun rrd verify` must pass; returns `rerun rrd print`'s listing."""
    done = subprocess.run([str(RERUN), "rrd", "verify", str(path)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return subprocess.run([str(RERUN), "rrd", "print", str(path)], capture_output=True,
                          text=True, timeout=120, check=True).stdout


def header_of(ep: EpisodeData, episode_id: int, cluster: int) -> pb.EpisodeHeader:
    """What the replay puts on replay/inserted for a stored episode."""
    return pb.EpisodeHeader(
        schema_version=SCHEMA_VERSION, episode_id=episode_id, actor_id=ep.actor_id, seq=ep.seq,
        success=ep.success, final_achieved_goal=array_to_msg(ep.ag[-1]),
        desired_goal=array_to_msg(ep.g[-1]), cluster=cluster, policy_version=ep.policy_version)


def run_episodes(n: int, seed: int = 0) -> list[EpisodeData]:
    """Push episodes; every third one ends on its goal (a success)."""
    rng = np.random.default_rng(seed)
    episodes = []
    for i in range(n):
        ep = random_episode(SPEC, rng, actor_id="actor-0", seq=i)
        if i % 3 == 0:
            ag = ep.ag.copy()
            ag[-1] = ep.g[-1] + 0.01
            ep = dataclasses.replace(ep, ag=ag, success=True)
        episodes.append(dataclasses.replace(ep, policy_version=i // 2))
    return episodes


# --------------------------------------------------------------------------- pure mapping


def test_header_outcome_is_the_offline_summary_of_the_episode() -> None:
    ep = run_episodes(2)[1]
    outcome = header_outcome(header_of(ep, 7, cluster=2), SPEC)
    assert (outcome.episode_id, outcome.cluster, outcome.actor_id, outcome.seq) == (7, 2,
                                                                                  "actor-0", 1)
    assert outcome.final_distance == pytest.approx(float(np.linalg.norm(ep.ag[-1] - ep.g[-1])))
    assert outcome.success is (outcome.final_distance < SPEC.distance_threshold)
    np.testing.assert_array_equal(outcome.desired_goal, ep.g[-1])
    ag = ep.ag.copy()
    ag[-1] = ep.g[-1] + np.array([0.049, 0.0, 0.0], np.float32)
    assert header_outcome(header_of(dataclasses.replace(ep, ag=ag), 8, -1), SPEC).success
    ag[-1] = ep.g[-1] + np.array([0.051, 0.0, 0.0], np.float32)
    assert not header_outcome(header_of(dataclasses.replace(ep, ag=ag), 8, -1), SPEC).success


def _drop(field: str):
    return lambda h: h.ClearField(field)


def _set_goal(value: np.ndarray):
    return lambda h: array_to_msg(value, out=h.desired_goal)


@pytest.mark.parametrize(
    ("mutate", "reason"),
    [(_drop("final_achieved_goal"), "missing_field"),
     (_set_goal(np.zeros(2, np.float32)), "bad_shape"),
     (_set_goal(np.array([0.0, np.inf, 0.0], np.float32)), "non_finite"),
     (lambda h: setattr(h, "cluster", -2), "bad_value")],
    ids=["missing-goal", "2d-goal", "inf-goal", "cluster-below-minus-1"],
)
def test_bad_headers_are_refused_with_a_reason(mutate, reason: str) -> None:
    header = header_of(run_episodes(1)[0], 0, cluster=-1)
    mutate(header)
    with pytest.raises(InvalidMessage) as err:
        header_outcome(header, SPEC)
    assert err.value.reason == reason


# --------------------------------------------------------------------------- real recordings


def test_live_recording_matches_hercs_view_of_the_same_run(tmp_path: Path) -> None:
    """12 episodes, a cluster model after the 6th, two epochs of learner metrics: the live
    recording and `hercs view --episodes 0::4` of the run's log hold the same rows."""
    episodes = run_episodes(12)
    centroids = np.random.default_rng(1).uniform(-1, 1, (3, 3)).astype(np.float32)
    model = pb.ClusterModel(schema_version=SCHEMA_VERSION, version=1,
                            centroids=array_to_msg(centroids), fitted_on=5, failures_seen=6)
    rows = [{"epoch": 1, "episodes": 6, "success_rate": 0.25, "env_steps_per_s": 400.5},
            {"epoch": 2, "episodes": 12, "success_rate": 0.5, "env_steps_per_s": 410.0}]

    # offline: the episode log and metrics.csv, as the replay and the learner write them
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    with EpisodeLogWriter(RunDir(run_dir).episode_log, run="t", task="push") as writer:
        for i, ep in enumerate(episodes):
            if i == 6:
                writer.append_cluster_model(model)
            writer.append_episode(episode_to_msg(ep, run="t", task="push"), episode_id=i)
    RunDir(run_dir).metrics.write_text("epoch,episodes,success_rate,env_steps_per_s\n" + "".join(
        f"{r['epoch']},{r['episodes']},{r['success_rate']},{r['env_steps_per_s']}\n"
        for r in rows))
    offline = tmp_path / "offline.rrd"
    assert main(["view", str(run_dir), "--episodes", "0::4", "--save", str(offline)]) == 0

    # live: the same run as messages, in the order a live view receives them
    live = tmp_path / "live.rrd"
    rec = rr.RecordingStream("hercs")
    rec.save(live)
    recorder = LiveRecorder(rr, rec, spec=SPEC, k=3, episode_every=4)
    recorder.start()
    fetched = []
    for i, ep in enumerate(episodes):
        if i == 6:
            assert recorder.on_cluster_model(model)
            assert not recorder.on_cluster_model(model), "a model is drawn once"
        cluster = -1 if i < 6 else int(assign_clusters(ep.ag[-1:], centroids)[0])
        if recorder.on_header(header_of(ep, i, cluster)):
            fetched.append(i)
            recorder.on_episode(episode_to_msg(ep, run="t", task="push"), episode_id=i)
        recorder.commit()
        if i in (5, 11):  # the learner's row of an epoch; other services' metrics are ignored
            row = rows[i // 6]
            recorder.on_status(pb.ReplayStatus(cluster_sizes=[i, 1, 0]))
            assert not recorder.on_metrics(pb.Metrics(service="evaluator/evaluator-0",
                                                      values={"success_rate": 0.9}))
            assert recorder.on_metrics(pb.Metrics(service="learner/learner-0",
                                                  values={**row, "epochs": 2}))
            assert not recorder.on_metrics(pb.Metrics(service="learner/learner-0",
                                                      values=row)), "an epoch is drawn once"
    rec.disconnect()
    assert fetched == [0, 4, 8]
    assert (recorder.headers, recorder.trajectories, recorder.models, recorder.epochs) == (
        12, 3, 1, 2)

    printed = verify(live)
    for entity in ("/world", "/world/episodes/000000/gripper", "/world/episodes/000004/object",
                   "/world/episodes/000008/goal", "/world/centroids", "/world/failed_goals",
                   "/episodes/success", "/episodes/final_distance", "/episodes/cluster",
                   "/log/episodes", "/log/cluster_models", "/curves/success_rate",
                   "/curves/env_steps_per_s", "/curves/episodes", "/curves/cluster_sizes"):
        assert f" - {entity} - " in printed, entity
    assert "/world/episodes/000005/" not in printed and "/curves/epochs" not in printed

    got, want = rrd_rows(live), rrd_rows(offline)
    same = ["/episodes/success", "/episodes/final_distance", "/episodes/cluster",
            "/world/centroids", "/world/failed_goals", "/log/episodes", "/log/cluster_models",
            "/curves/success_rate", "/curves/env_steps_per_s", "/curves/episodes"]
    same += [f"/world/episodes/{i:06d}/{part}" for i in (0, 4, 8)
             for part in ("gripper", "object", "goal")]
    for entity in same:
        assert want[entity], entity
        assert sorted(map(repr, got[entity])) == sorted(map(repr, want[entity])), entity
    # the failed goals grow along `episode`: at the model (6) and each drawn episode
    failed = {r["episode"]: len(r["Points3D:positions"]) for r in got["/world/failed_goals"]}
    fails = np.cumsum([not ep.success for ep in episodes])
    assert failed == {i: int(fails[i]) for i in (0, 4, 6, 8)}
    # curves sit on `epoch` and at each epoch's last episode
    assert [(r["epoch"], r["episode"], r["Scalars:scalars"])
            for r in got["/curves/cluster_sizes"]] == [(1, 5, [5.0, 1.0, 0.0]),
                                                       (2, 11, [11.0, 1.0, 0.0])]


def test_failed_goals_are_the_newest_max_failed_goals(tmp_path: Path) -> None:
    episodes = [ep for ep in run_episodes(12) if not ep.success][:6]
    path = tmp_path / "live.rrd"
    rec = rr.RecordingStream("hercs")
    rec.save(path)
    recorder = LiveRecorder(rr, rec, spec=SPEC, k=8, episode_every=5, max_failed_goals=3)
    for i, ep in enumerate(episodes):
        recorder.on_header(header_of(ep, i, -1))
    rec.disconnect()
    logged = {r["episode"]: r["Points3D:positions"] for r in rrd_rows(path)["/world/failed_goals"]}
    np.testing.assert_allclose(logged[5], [ep.g[-1] for ep in episodes[3:6]])


def test_a_model_before_any_header_is_drawn_at_the_first_header(tmp_path: Path) -> None:
    """A live view joining a running run gets the current model first (a late joiner)."""
    path = tmp_path / "live.rrd"
    rec = rr.RecordingStream("hercs")
    rec.save(path)
    recorder = LiveRecorder(rr, rec, spec=SPEC, k=2, episode_every=100)
    centroids = np.array([[1.0, 0.5, 0.4], [1.3, 0.9, 0.4]], np.float32)
    assert recorder.on_cluster_model(pb.ClusterModel(
        schema_version=SCHEMA_VERSION, version=7, centroids=array_to_msg(centroids)))
    older = pb.ClusterModel(schema_version=SCHEMA_VERSION, version=6,
                            centroids=array_to_msg(centroids))
    assert not recorder.on_cluster_model(older)
    with pytest.raises(InvalidMessage):  # k = 3 centroids for a k = 2 run
        recorder.on_cluster_model(pb.ClusterModel(
            schema_version=SCHEMA_VERSION, version=8,
            centroids=array_to_msg(np.zeros((3, 3), np.float32))))
    for i, ep in enumerate(run_episodes(3), start=500):
        recorder.on_header(header_of(ep, i, 0))
    rec.disconnect()
    rows = rrd_rows(path)
    assert [r["episode"] for r in rows["/world/centroids"]] == [500]
    assert recorder.models == 1


def test_episode_every_zero_draws_no_trajectory(tmp_path: Path) -> None:
    rec = rr.RecordingStream("hercs")
    rec.save(tmp_path / "live.rrd")
    recorder = LiveRecorder(rr, rec, spec=SPEC, k=8, episode_every=0)
    assert not any(recorder.on_header(header_of(ep, i, -1))
                   for i, ep in enumerate(run_episodes(3)))
    rec.disconnect()
    with pytest.raises(ConfigError, match="episode_every: got -1"):
        LiveRecorder(rr, rec, spec=SPEC, k=8, episode_every=-1)


# --------------------------------------------------------------------------- a viewer going away


def test_a_viewer_that_goes_away_is_reported_once_and_the_file_keeps_growing(
        tmp_path: Path, caplog) -> None:
    port = free_port()
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    with rerun_viewer(port, tmp_path / "received.rrd") as viewer:
        saved = tmp_path / "live.rrd"
        rec = rr.RecordingStream("hercs")
        rec.set_sinks(rr.GrpcSink(url), rr.FileSink(saved))
        recorder = LiveRecorder(rr, rec, spec=SPEC, k=8, episode_every=0)
        health = ViewerHealth(rec, viewer=url, save=str(saved))
        episodes = run_episodes(6)
        for i, ep in enumerate(episodes[:3]):
            recorder.on_header(header_of(ep, i, -1))
        recorder.commit()
        assert health.check()

        viewer.send_signal(signal.SIGKILL)
        viewer.wait(10)
        with caplog.at_level(logging.WARNING, logger="hercs.live"):
            for i, ep in enumerate(episodes[3:], start=3):
                recorder.on_header(header_of(ep, i, -1))
                recorder.commit()
                health.check()  # never raises
            deadline = time.monotonic() + 10
            while health.check():  # the gRPC client may notice only on a later flush
                assert time.monotonic() < deadline, "the dead viewer was never noticed"
                time.sleep(0.2)
            health.check()
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert len(warnings) == 1 and "cannot be reached or went away" in warnings[0], warnings
        assert not health.ok and health.errors >= 1
        rec.disconnect()
    verify(saved)
    success = rrd_rows(saved)["/episodes/success"]
    assert sorted(r["episode"] for r in success if "episode" in r) == list(range(6))
