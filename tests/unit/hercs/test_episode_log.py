"""The episode log keeps every acked episode: it reads back with the plain mcap reader, survives
SIGKILL and torn tails, continues across restarts in segments, and converts with Rerun."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from episode_log_child import RUN, make_episode
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_registry import task_spec
from hercs.run.rundir import RunDir
from hercs.run.runlog import (
    TOPIC_CLUSTER_MODEL,
    TOPIC_EPISODES,
    TOPIC_EVAL_RESULT,
    TOPIC_SCENE,
    TOPIC_SCENE_POINTS,
    EpisodeLog,
    EpisodeLogError,
    EpisodeLogWriter,
    read_cluster_models,
    read_episode_messages,
    read_eval_results,
    read_messages,
    run_start_ns,
    scan_segment,
    scene,
    seal_segment,
    segment_paths,
)
from hercs.wire.codec import array_to_msg, msg_to_array

CHILD = "tests.unit.hercs.episode_log_child"  # run as a module from the checkout: it imports bench
RERUN = Path(sys.executable).with_name("rerun")
ARRAYS = ("obs", "ag", "g", "actions")


def assert_same_episode(got: pb.Episode, want: pb.Episode) -> None:
    for name in ARRAYS:
        np.testing.assert_array_equal(msg_to_array(getattr(got, name)),
                                      msg_to_array(getattr(want, name)), err_msg=name)
    assert (got.actor_id, got.seq, got.success, got.policy_version, got.run, got.task) == (
        want.actor_id, want.seq, want.success, want.policy_version, want.run, want.task)
    assert got == want


def cluster_model() -> pb.ClusterModel:
    centroids = np.random.default_rng(5).uniform(-1, 1, size=(8, 3)).astype(np.float32)
    return pb.ClusterModel(schema_version=1, version=3, centroids=array_to_msg(centroids),
                           fitted_on=150, failures_seen=450)


def eval_result() -> pb.EvalResult:
    return pb.EvalResult(schema_version=1, epoch=7, weights_version=70, episodes=20,
                         success_rate=0.35, mean_final_distance=0.081)


def write_log(path: Path, ids: range, task: str = "push", *, scene: bool = True
              ) -> tuple[EpisodeLogWriter, list[int]]:
    """Append episodes `ids` (not closed: as a killed writer leaves it); returns the writer
    and the file size after each append. `scene=False`: one chunk per episode (no scene
    chunks between them), for the tests that count chunks."""
    writer = EpisodeLogWriter(path, run=RUN, task=task, scene=scene)
    sizes = []
    for i in ids:
        writer.append_episode(make_episode(i, task), episode_id=i)
        writer.flush_scenes()  # a kill-like cut must not race the scene thread's writes
        sizes.append(path.stat().st_size)
    return writer, sizes


@pytest.mark.parametrize("task", ["push", "reach"])
def test_closed_log_reads_back_with_plain_mcap_reader(tmp_path: Path, task: str) -> None:
    n, T = 9, task_spec(task).episode_steps
    S = 1_795_000_000 * 10**9  # the run's start: every log_time is an offset from it
    path = RunDir(tmp_path).episode_log
    with EpisodeLogWriter(path, run=RUN, task=task, start_time_ns=S) as writer:
        for i in range(4):
            writer.append_episode(make_episode(i, task), episode_id=i, log_time_ns=1_000 + i)
        writer.append_cluster_model(cluster_model(), log_time_ns=5_000)
        writer.append_many([(i, make_episode(i, task)) for i in range(4, n)], log_time_ns=6_000)
        writer.append_eval_result(eval_result())

    by_topic: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            by_topic.setdefault(channel.topic, []).append((message, decoded))
    assert summary is not None and summary.statistics.message_count == n * (1 + 2 * (T + 1)) + 2

    episodes = by_topic[TOPIC_EPISODES]
    assert [m.sequence for m, _ in episodes] == list(range(n))
    for message, decoded in episodes:
        assert_same_episode(pb.Episode.FromString(decoded.SerializeToString()),
                            make_episode(message.sequence, task))
        assert message.log_time == S + scene.episode_start_ns(message.sequence, T)
    assert [m.publish_time for m, _ in episodes] == [1_000, 1_001, 1_002, 1_003] + [6_000] * 5
    [(model_msg, model)] = by_topic[TOPIC_CLUSTER_MODEL]
    assert model.SerializeToString() == cluster_model().SerializeToString()
    assert model_msg.sequence == 3 and model_msg.publish_time == 5_000
    assert model_msg.log_time == S + scene.episode_start_ns(4, T) - scene.STEP_NS  # after ep 3
    [(_, result)] = by_topic[TOPIC_EVAL_RESULT]
    assert result.SerializeToString() == eval_result().SerializeToString()

    assert len(by_topic[TOPIC_SCENE]) == len(by_topic[TOPIC_SCENE_POINTS]) == n * (T + 1)
    episode = make_episode(6, task)
    obs, g = msg_to_array(episode.obs), msg_to_array(episode.g)
    steps = [(m, d) for m, d in by_topic[TOPIC_SCENE] if m.sequence == 6]
    assert [m.log_time for m, _ in steps] == [S + t for t in scene.step_times_ns(6, T + 1, T)]
    for t in (0, 17, T):
        entities = {e.id: e for e in steps[t][1].entities}
        assert set(entities) == ({"gripper", "goal"} if task == "reach"
                                 else {"gripper", "object", "goal"})
        position = entities["gripper"].spheres[0].pose.position
        np.testing.assert_allclose([position.x, position.y, position.z], obs[t, 0:3], rtol=1e-6)
        position = entities["goal"].spheres[0].pose.position
        np.testing.assert_allclose([position.x, position.y, position.z], g[min(t, T - 1)],
                                   rtol=1e-6)
        if task != "reach":
            position = entities["object"].cubes[0].pose.position
            np.testing.assert_allclose([position.x, position.y, position.z], obs[t, 3:6],
                                       rtol=1e-6)
    cloud = PointCloud.FromString(
        [d for m, d in by_topic[TOPIC_SCENE_POINTS] if m.sequence == 6][T].SerializeToString())
    points = np.frombuffer(cloud.data, dtype=[("xyz", "<f4", 3), ("rgba", "u1", 4)])
    np.testing.assert_array_equal(points["xyz"][0], obs[T, 0:3])
    np.testing.assert_array_equal(points["xyz"][-1], g[-1])
    assert len(points) == (2 if task == "reach" else 3)

    # our tolerant reader agrees with mcap's indexed reader on a finished file
    assert [i for i, _ in read_episode_messages(path)] == list(range(n))
    assert [m.version for m in read_cluster_models(path)] == [3]
    assert [r.epoch for r in read_eval_results(path)] == [7]


def test_invalid_appends_write_nothing_and_leave_the_writer_usable(tmp_path: Path) -> None:
    path = RunDir(tmp_path).episode_log
    writer = EpisodeLogWriter(path, run=RUN, task="push")
    writer.append_episode(make_episode(0, "push"), episode_id=5)
    writer.flush_scenes()  # episode 5's scene comes from the scene thread
    size = path.stat().st_size
    with pytest.raises(ValueError, match="ids must increase"):
        writer.append_many([(6, make_episode(1, "push")), (6, make_episode(2, "push"))])
    with pytest.raises(ValueError, match="uint32"):
        writer.append_episode(make_episode(1, "push"), episode_id=2**32)
    long = make_episode(1, "push")
    long.obs.CopyFrom(array_to_msg(np.zeros((80, 25), np.float32)))
    with pytest.raises(ValueError, match="at most T\\+1=51"):
        writer.append_episode(long, episode_id=6)
    with pytest.raises(ValueError, match="task 'reach' in the log of run 'log-test' task 'push'"):
        writer.append_episode(make_episode(1, "reach"), episode_id=6)
    assert path.stat().st_size == size
    writer.append_episode(make_episode(2, "push"), episode_id=6)
    writer.close()
    writer.close()
    with pytest.raises(EpisodeLogError, match="after close"):
        writer.append_episode(make_episode(3, "push"), episode_id=7)
    assert [i for i, _ in read_episode_messages(path)] == [5, 6]
    with pytest.raises(EpisodeLogError, match="never overwritten"):
        EpisodeLogWriter(path, run=RUN, task="push")


def test_plain_mcap_reader_cannot_read_a_killed_writers_file(tmp_path: Path) -> None:
    """Why recovery has its own reader: mcap 1.6 reads the footer first and fails."""
    path = RunDir(tmp_path).episode_log
    _, _ = write_log(path, range(3))
    with open(path, "rb") as f, pytest.raises((McapError, struct.error)):
        list(make_reader(f).iter_messages())
    assert [i for i, _ in read_episode_messages(path)] == [0, 1, 2]


def test_torn_tail_anywhere_yields_exactly_the_complete_chunks(tmp_path: Path) -> None:
    """Cut the file at any byte: the reader yields the episodes whose chunk is complete (every
    acked one, since an append returns after its chunk and indexes are fsynced; the episode
    being written when the cut happened too, if its chunk made it) and never raises."""
    full = tmp_path / "full.mcap"
    writer, sizes = write_log(full, range(4), scene=False)
    writer.close()  # appends the summary after the data: mcap's own index of the chunks
    with open(full, "rb") as f:
        chunk_ends = [c.chunk_start_offset + c.chunk_length
                      for c in make_reader(f).get_summary().chunk_indexes]
    data = full.read_bytes()[:sizes[-1]]
    assert len(chunk_ends) == 4 and chunk_ends[-1] < sizes[-1]
    rng = np.random.default_rng(11)
    boundaries = [0, 8, *sizes, *chunk_ends]
    cuts = {c for b in boundaries for c in range(b - 10, b + 11) if 0 <= c <= len(data)}
    cuts |= set(rng.integers(0, len(data) + 1, size=150).tolist())
    cut_file = tmp_path / "cut.mcap"
    for cut in sorted(cuts):
        cut_file.write_bytes(data[:cut])
        acked = [i for i, size in enumerate(sizes) if size <= cut]
        complete = [i for i, end in enumerate(chunk_ends) if end <= cut]
        got = list(read_episode_messages(cut_file))
        assert [i for i, _ in got] == complete, f"cut at {cut}"
        assert set(acked) <= set(complete)
        for i, episode in got:
            assert episode == make_episode(i, "push")
    # a sealed cut is a complete MCAP file that the plain reader opens through its summary
    for cut in (sizes[1] + 1, chunk_ends[2] - 1, chunk_ends[2] + 9, sizes[3] - 1):
        complete = [i for i, end in enumerate(chunk_ends) if end <= cut]
        cut_file.write_bytes(data[:cut])
        scan = seal_segment(cut_file)
        assert scan.finished and scan.dropped_bytes == 0 and scan.messages is not None
        assert seal_segment(cut_file).finished  # idempotent
        with open(cut_file, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
            ids = [m.sequence for _, _, m, _ in reader.iter_decoded_messages(TOPIC_EPISODES)]
        assert summary is not None and len(summary.chunk_indexes) == len(complete)
        assert ids == complete


def test_garbage_and_corrupt_tails(tmp_path: Path) -> None:
    path = RunDir(tmp_path).episode_log
    _, sizes = write_log(path, range(3), scene=False)
    data = path.read_bytes()
    for tail in (bytes(4096), np.random.default_rng(3).bytes(4096)):
        path.write_bytes(data + tail)
        assert [i for i, _ in read_episode_messages(path)] == [0, 1, 2]
    # a damaged last chunk (power loss before its fsync) is the torn tail
    last_chunk_body = sizes[1] + 200
    damaged = bytearray(data)
    damaged[last_chunk_body] ^= 0xFF
    path.write_bytes(bytes(damaged))
    assert [i for i, _ in read_episode_messages(path)] == [0, 1]
    assert scan_segment(path).valid_end == sizes[1]
    # a damaged chunk followed by an intact one is corruption: refuse, do not drop data
    damaged = bytearray(data)
    damaged[sizes[0] + 200] ^= 0xFF
    path.write_bytes(bytes(damaged))
    with pytest.raises(EpisodeLogError, match="damaged in the middle"):
        list(read_episode_messages(path))


@pytest.mark.parametrize(("acks_before_kill", "delay_s"), [(1, 0.0), (6, 0.001), (25, 0.0025)],
                         ids=["kill-after-1-ack", "kill-1ms-after-6-acks",
                              "kill-2.5ms-after-25-acks"])
def test_sigkill_mid_stream_loses_no_acked_episode(tmp_path: Path, acks_before_kill: int,
                                                   delay_s: float) -> None:
    """The child acks (prints) an id only after append_episode returned; the kill lands while
    it builds or writes the next one."""
    path = RunDir(tmp_path).episode_log
    child = subprocess.Popen([sys.executable, "-m", CHILD, str(path), "push"],
                             stdout=subprocess.PIPE, text=True, cwd=Path(__file__).parents[3])
    acked: list[int] = []
    try:
        assert child.stdout is not None
        while len(acked) < acks_before_kill:
            line = child.stdout.readline()
            assert line, f"child exited with {child.wait()} after {len(acked)} acks"
            acked.append(int(line))
        time.sleep(delay_s)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
    assert child.returncode == -signal.SIGKILL
    assert acked == list(range(acks_before_kill))

    recovered = list(read_episode_messages(path))
    ids = [i for i, _ in recovered]
    assert len(ids) >= acks_before_kill
    assert ids == list(range(len(ids)))  # every acked id in order, and any appended before the kill
    for i, episode in recovered:
        assert_same_episode(episode, make_episode(i, "push"))

    writer, again = EpisodeLog.open(tmp_path, run=RUN, task="push")
    assert [i for i, _ in again] == ids
    writer.close()
    with open(tmp_path / "episodes.000.mcap", "rb") as f:  # sealed: plain reader works
        n = sum(1 for _ in make_reader(f).iter_messages(topics=[TOPIC_EPISODES]))
    assert n == len(ids)


@pytest.mark.parametrize("max_file_bytes", [150_000, 200_000],
                         ids=["cut-in-chunk", "cut-in-message-index"])  # with these seeds
def test_a_write_failing_part_way_loses_no_acked_episode(tmp_path: Path,
                                                         max_file_bytes: int) -> None:
    """A file size limit (as a full disk) makes a write fail half done: the append raises,
    nothing after it is accepted, and recovery yields every acked episode, plus the failed
    one if its chunk was complete before the failing write (its message index was not)."""
    path = RunDir(tmp_path).episode_log
    out = subprocess.run([sys.executable, "-m", CHILD, str(path), "push",
                          str(max_file_bytes)],
                         capture_output=True, text=True, timeout=60, check=True,
                         cwd=Path(__file__).parents[3]).stdout.splitlines()
    assert out[-2].startswith("failed") and out[-1] == "refused", out[-3:]
    acked = [int(line) for line in out[:-2]]
    assert acked == list(range(len(acked))) and len(acked) >= 5
    scan = scan_segment(path)
    assert scan.size == max_file_bytes and scan.dropped_bytes > 0  # a torn chunk at the tail
    recovered = list(read_episode_messages(path))
    ids = [i for i, _ in recovered]
    assert ids in (acked, [*acked, len(acked)])
    for i, episode in recovered:
        assert_same_episode(episode, make_episode(i, "push"))


def test_restart_continues_in_a_new_segment(tmp_path: Path) -> None:
    before = time.time_ns()
    writer, recovered = EpisodeLog.open(tmp_path, run=RUN, task="push")
    assert list(recovered) == []
    start = writer.start_time_ns  # the run's real start: the first segment's creation
    assert before <= start <= time.time_ns()
    live = RunDir(tmp_path).episode_log
    for i in range(6):
        size_before = live.stat().st_size
        writer.append_episode(make_episode(i, "push"), episode_id=i)
        writer.flush_scenes()
    os.truncate(live, size_before + 500)  # crash inside episode 5's chunk: it was never acked
    del writer  # never closed, like a killed process

    writer, recovered = EpisodeLog.open(tmp_path, run=RUN, task="push")
    assert [i for i, _ in recovered] == [0, 1, 2, 3, 4]
    writer.append_cluster_model(cluster_model())
    for i in range(5, 9):
        writer.append_episode(make_episode(i, "push"), episode_id=i)
    writer.close()

    writer, recovered = EpisodeLog.open(tmp_path, run=RUN, task="push")
    assert [i for i, _ in recovered] == list(range(9))
    writer.append_many([(i, make_episode(i, "push")) for i in (9, 10)])
    writer.close()

    assert [p.name for p in segment_paths(tmp_path)] == [
        "episodes.000.mcap", "episodes.001.mcap", "episodes.mcap"]
    everything = list(EpisodeLog(tmp_path).episodes())
    assert [i for i, _ in everything] == list(range(11))
    for i, episode in everything:
        assert_same_episode(episode, make_episode(i, "push"))
    assert [m.version for m in read_cluster_models(tmp_path)] == [3]
    for segment in segment_paths(tmp_path):
        with open(segment, "rb") as f:
            assert make_reader(f).get_summary() is not None, segment.name
    # one timeline across the restarts, from the run's start (a viewer shows its real date)
    assert run_start_ns(segment_paths(tmp_path)) == start
    T = task_spec("push").episode_steps
    assert [(m.sequence, m.log_time_ns) for m in read_messages(tmp_path, [TOPIC_EPISODES])] == [
        (i, start + scene.episode_start_ns(i, T)) for i in range(11)]


def test_open_drops_an_empty_killed_segment_and_refuses_another_runs_log(
        tmp_path: Path) -> None:
    EpisodeLogWriter(RunDir(tmp_path).episode_log, run=RUN, task="push")  # killed: no episode
    writer, recovered = EpisodeLog.open(tmp_path, run=RUN, task="push")
    assert list(recovered) == []
    writer.append_episode(make_episode(0, "push"), episode_id=0)
    writer.close()
    assert [p.name for p in segment_paths(tmp_path)] == ["episodes.mcap"]

    with pytest.raises(EpisodeLogError, match="run 'log-test' task 'push'"):
        EpisodeLog.open(tmp_path, run="another-run", task="push")
    assert [p.name for p in segment_paths(tmp_path)] == ["episodes.mcap"]  # left untouched


@pytest.mark.skipif(not RERUN.exists(), reason=f"the rerun CLI is not installed at {RERUN}")
def test_rerun_converts_and_verifies_closed_and_sealed_logs(tmp_path: Path) -> None:
    closed = tmp_path / "closed.mcap"
    with EpisodeLogWriter(closed, run=RUN, task="pick") as writer:
        writer.append_many([(i, make_episode(i, "pick")) for i in range(3)])
        writer.append_eval_result(eval_result())
    sealed = tmp_path / "sealed.mcap"
    _, sizes = write_log(sealed, range(3), task="pick")
    os.truncate(sealed, sizes[-1] - 50)
    seal_segment(sealed)
    env = {**os.environ, "RERUN_ANALYTICS": "0"}  # no first-run notice or telemetry
    for log_path in (closed, sealed):
        rrd = log_path.with_suffix(".rrd")
        # `mcap convert` exits 0 even when it cannot load the file: `rrd verify` is the check
        subprocess.run([RERUN, "mcap", "convert", log_path, "-o", rrd], check=True, env=env,
                       capture_output=True, timeout=60)
        verify = subprocess.run([RERUN, "rrd", "verify", rrd], env=env, capture_output=True,
                                text=True, timeout=60)
        assert verify.returncode == 0, verify.stdout + verify.stderr
        printed = subprocess.run([RERUN, "rrd", "print", rrd], env=env, capture_output=True,
                                 text=True, check=True, timeout=60).stdout
        assert "/scene/points" in printed and "Points3D:positions" in printed
    # Rerun's clock for the raw log starts at the run's real start, not at 1970
    info = subprocess.run([RERUN, "mcap", "info", closed], env=env, capture_output=True,
                          text=True, check=True, timeout=60).stdout
    started = datetime.fromtimestamp(writer.start_time_ns // 10**9, UTC)
    [start_line] = [line for line in info.splitlines() if line.strip().startswith("Start")]
    assert started.strftime("%Y-%m-%dT%H:%M:%S") in start_line, info
