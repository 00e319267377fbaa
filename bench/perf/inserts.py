"""Acked inserts per second of the replay table with its real episode log, in process.

    python -m bench.perf.inserts [--quick] [--out docs/results/inserts]

N insert threads into one `ReplayTable` on a real fsynced log, serial against group commit,
with and without scenes. Method and results: docs/results/inserts.md, docs/PERFORMANCE.md §6."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import mcap.writer
import numpy as np
import zstandard
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from bench.common import REPO, git_commit
from bench.perf.scene_reference import reference_point_clouds, reference_scene_updates
from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.builder import ReplayBuilder
from hercs.replay_service.table import Stored
from hercs.run.runlog import RecoveringLogWriter
from hercs.run.runlog.format import TOPIC_SCENE, TOPIC_SCENE_POINTS
from hercs.run.runlog.mcap_bulk import reuse_zstd_contexts
from hercs.run.runlog.writer import EpisodeLogWriter, _PreparedEpisode
from hercs.wire.codec import episode_to_msg

BOUNDED_SEGMENT = 100
"""Episodes per segment of the bounded-log variant (the default's 5,000 would start none)."""
BEFORE = "group commit, scene path before 2026-11-27"
VARIANTS = {
    "serial, scene on the ack path": (1, True, True, 0),
    "serial": (1, True, False, 0),
    "group commit": (4, True, False, 0),
    BEFORE: (4, True, False, 0),
    "group commit, no scene": (4, False, False, 0),
    "group commit, bounded log": (4, True, False, BOUNDED_SEGMENT),
}
"""name → (threads, log the scene, wait for the scene before the ack, episodes per segment:
0 for one growing segment)."""


@contextlib.contextmanager
def _scene_path_before() -> Iterator[None]:
    """The log's scene path as of 905a24b, for one measurement: each message built step by
    step and added with `add_message`, a new zstd compressor per chunk."""
    build, write = EpisodeLogWriter._scene_messages, EpisodeLogWriter._write_rows

    def messages(self: EpisodeLogWriter, episode: _PreparedEpisode
                 ) -> tuple[list[bytes], list[bytes]]:
        p, times, msg = episode.positions, episode.times_ns, episode.msg
        labels = {"episode_id": str(episode.episode_id), "actor_id": msg.actor_id,
                  "seq": str(msg.seq), "success": str(bool(msg.success)).lower()}
        return (reference_scene_updates(p, times, goal_diameter=2 * self._spec.distance_threshold,
                                        labels=labels), reference_point_clouds(p, times))

    def rows(self: EpisodeLogWriter, episode: _PreparedEpisode,
             columns: tuple[list[bytes], list[bytes]]) -> None:
        channels = (self._channel(TOPIC_SCENE, SceneUpdate()),
                    self._channel(TOPIC_SCENE_POINTS, PointCloud()))
        for t, update, cloud in zip(episode.times_ns, *columns, strict=True):
            for channel, data in zip(channels, (update, cloud), strict=True):
                self._mcap.add_message(channel_id=channel, log_time=t, data=data,
                                       publish_time=t, sequence=episode.episode_id)
        self._mcap.flush()

    EpisodeLogWriter._scene_messages, EpisodeLogWriter._write_rows = messages, rows  # type: ignore
    mcap.writer.zstandard = zstandard  # type: ignore[attr-defined]
    try:
        yield
    finally:
        EpisodeLogWriter._scene_messages, EpisodeLogWriter._write_rows = build, write
        reuse_zstd_contexts()


class _Acked:
    def __init__(self, counter: list[int], done: threading.Event) -> None:
        self.counter, self.done_event = counter, done

    def done(self, result: Stored) -> None:
        self.counter[0] += 1
        self.done_event.set()

    def fail(self, reason: str, detail: str) -> None:
        raise RuntimeError(f"insert refused: {reason}: {detail}")


class _SceneOnAckPath:
    """The log as before: an append returns only when its episodes' scenes are written."""

    def __init__(self, log: RecoveringLogWriter) -> None:
        self.log = log

    def append_many(self, episodes: list[tuple[int, pb.Episode]]) -> None:
        self.log.append_many(episodes)
        writer = self.log._writer  # the live segment's writer
        if writer is not None:
            writer.flush_scenes()

    def append_cluster_model(self, msg: pb.ClusterModel) -> None:
        self.log.append_cluster_model(msg)

    def append_eval_result(self, msg: pb.EvalResult) -> None:
        self.log.append_eval_result(msg)

    def rotation_due(self) -> bool:
        return self.log.rotation_due()

    def start_segment(self, state: pb.ReplayState) -> None:
        self.log.start_segment(state)


def measure(name: str, *, window_s: float, pool: list, workdir: Path) -> dict[str, float]:
    """Acked episodes/s in the window; with every scene written: the episodes acked from its
    start until the workers stopped, over the time until their scenes were all written."""
    with _scene_path_before() if name == BEFORE else contextlib.nullcontext():
        return _measure(name, window_s=window_s, pool=pool, workdir=workdir)


def _measure(name: str, *, window_s: float, pool: list, workdir: Path) -> dict[str, float]:
    threads, scene, scene_on_path, segment_episodes = VARIANTS[name]
    # synthetic episodes carry no weights version: no lag bound (the insert path is measured)
    config = apply_overrides(HercsConfig(), ["task.name=push", "run.name=bench",
                                             "replay.free_run=true",
                                             "training.max_policy_lag=-1"])
    run_dir = Path(tempfile.mkdtemp(dir=workdir))
    log, _ = RecoveringLogWriter.open(run_dir, run="bench", task="push", scene=scene,
                                      segment_episodes=segment_episodes,
                                      max_bytes=0 if segment_episodes else -1)
    sink = _SceneOnAckPath(log) if scene_on_path else log
    table = ReplayBuilder(config).table(rng=np.random.default_rng(0), log=sink)
    acked = [0]
    stop = threading.Event()

    def worker(index: int) -> None:
        seq = 0
        while not stop.is_set():
            data, msg = pool[seq % len(pool)]
            episode = dataclasses.replace(data, actor_id=f"a{index}", seq=seq)
            answered = threading.Event()
            table.insert(episode, record=msg, waiter=_Acked(acked, answered))
            answered.wait()  # one insert in flight per worker, as one actor's inserter
            seq += 1

    workers = [threading.Thread(target=worker, args=(i,), daemon=True) for i in range(threads)]
    for thread in workers:
        thread.start()
    time.sleep(0.3)  # warm-up: files created, first chunks written
    start, count = time.monotonic(), acked[0]
    time.sleep(window_s)  # the measurement window itself
    rate = (acked[0] - count) / (time.monotonic() - start)
    stop.set()
    for thread in workers:
        thread.join(30)
    writer = log._writer  # the live segment's (a bounded log's earlier ones are closed)
    if writer is not None:
        writer.flush_scenes()
    drained = (acked[0] - count) / (time.monotonic() - start)
    dropped = 0 if writer is None else writer.scenes_dropped
    log.close()
    return {"acked": rate, "with_scenes": drained, "dropped": float(dropped)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="short windows, one round")
    parser.add_argument("--out", default=str(REPO / "docs/results/inserts"))
    args = parser.parse_args(argv)
    window_s, rounds = (0.5, 1) if args.quick else (4.0, 3)
    spec = apply_overrides(HercsConfig(), ["task.name=push"]).task.spec
    rng = np.random.default_rng(0)
    pool = []
    for i in range(64):
        episode = random_episode(spec, rng, seq=i)
        pool.append((episode, episode_to_msg(episode, run="bench", task="push")))
    runs: dict[str, list[dict[str, float]]] = {name: [] for name in VARIANTS}
    with tempfile.TemporaryDirectory(dir=REPO) as workdir:  # the repository's disk
        for _ in range(rounds):
            for name in VARIANTS:
                runs[name].append(measure(name, window_s=window_s, pool=pool,
                                          workdir=Path(workdir)))
    rates = {name: [r["acked"] for r in rs] for name, rs in runs.items()}
    base = float(np.median(rates["serial, scene on the ack path"]))
    results = {name: {"episodes_per_s": float(np.median(r)), "rounds": r,
                      "with_scenes_rounds": [x["with_scenes"] for x in runs[name]],
                      "with_scenes_per_s": float(np.median([x["with_scenes"] for x in runs[name]])),
                      "scenes_dropped": int(sum(x["dropped"] for x in runs[name])),
                      "ratio": float(np.median(r)) / base} for name, r in rates.items()}
    now, before = runs["group commit"], runs[BEFORE]
    for key in ("acked", "with_scenes"):  # alternate rounds side by side: ratios per round
        results["group commit"][f"ratio_to_before_{key}"] = float(np.median(
            [a[key] / b[key] for a, b in zip(now, before, strict=True)]))
    command = "python -m bench.perf.inserts" + (" --quick" if args.quick else "")
    lines = ["# Replay inserts acked per second, in process", "",
             f"`{command}` — git {git_commit()}; {rounds} round(s) of {window_s:g} s per "
             "variant, median; FetchPush episodes, free run, log fsynced on this disk.", "",
             "| variant | threads | acked episodes/s | with every scene written | scenes dropped "
             "| ratio |", "|---|---|---|---|---|---|"]
    for name, row in results.items():
        lines.append(f"| {name} | {VARIANTS[name][0]} | {row['episodes_per_s']:.0f} | "
                     f"{row['with_scenes_per_s']:.0f} | {row['scenes_dropped']} | "
                     f"{row['ratio']:.2f} |")
    row = results["group commit"]
    lines += ["", "Group commit now against the scene path before, round by round (median of "
              f"the ratios): acked **{row['ratio_to_before_acked']:.2f}**, with every scene "
              f"written **{row['ratio_to_before_with_scenes']:.2f}**."]
    text = "\n".join(lines) + "\n"
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(
        {"git": git_commit(), "window_s": window_s, "rounds": rounds, "results": results},
        indent=2) + "\n")
    out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
