"""A replay's run directory as a SIGKILL leaves it, for bench/faults/replay_recovery.py: a real
episode log written as the replay writes it, its live segment left unsealed, and how to put the
directory back before each recovery.

    python -m bench.faults.killed_replay_log CONFIG EPISODES   # the writer child
"""


from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.common import REPO
from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides, load_yaml, save_yaml
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.builder import ReplayBuilder
from hercs.replay_service.table import Stored
from hercs.rl.cluster_model import ClusterModel
from hercs.rl.seeding import generator
from hercs.run.rundir import RunDir, run_dir_of
from hercs.run.runlog import LIVE_NAME, RecoveringLogWriter, segment_paths
from hercs.wire.codec import cluster_model_to_msg, episode_to_msg, msg_to_episode

RUN = "recovery"
T = 50
"""FetchPush's episode steps (`task.name=push`)."""
SCENE_FLUSH = 256
"""The writer waits for the scene thread every this many episodes: a replay fed at an
actor's pace draws every scene (a bulk insert would outrun SCENE_BACKLOG and drop some)."""


# -- the run directory: a log written as the replay writes it, left as a kill leaves it ----

def run_config(root: Path, *, endpoint: str, buffer: int | None,
               extra: list[str]) -> HercsConfig:
    overrides = ["task.name=push", f"run.name={RUN}", f"run.run_dir={root / 'runs'}",
                 f"transport.connect=[{endpoint}]", f"transport.listen=[{endpoint}]",
                 # the writer inserts synthetic episodes with no learner: no limiter, no lag
                 "replay.free_run=true", "training.max_policy_lag=-1"]
    if buffer is not None:
        overrides.append(f"replay.buffer_transitions={buffer}")
    return apply_overrides(HercsConfig(), overrides + extra)


def episode_msg(config: HercsConfig, seq: int) -> pb.Episode:
    """Episode `seq` of the bench's log (the same bytes every time it is asked for)."""
    spec = config.task.spec
    episode = random_episode(spec, np.random.default_rng(seq), actor_id="actor-0", seq=seq)
    return episode_to_msg(episode, run=RUN, task=spec.name)


class _Ack:
    def done(self, result: Stored) -> None:
        pass

    def fail(self, reason: str, detail: str) -> None:
        raise RuntimeError(f"insert refused: {reason}: {detail}")


def write_main(config_path: Path, episodes: int) -> int:
    """The writer child: `episodes` inserts through the replay's table and log, a cluster model
    every `cluster.fgb_size`, then an exit with the live segment unsealed (a kill)."""
    config = load_yaml(config_path)
    spec = config.task.spec
    run_dir = run_dir_of(config.run)
    log, _ = RecoveringLogWriter.open(
        run_dir, run=RUN, task=spec.name, scene=config.replay.log_scene,
        segment_episodes=config.replay.log_segment_episodes(config.capacity_episodes),
        max_bytes=config.replay.log_max_bytes, spec=spec)
    table = ReplayBuilder(config).table(rng=generator(config.run.seed, "replay"), log=log)
    rng = np.random.default_rng(1)
    every = config.cluster.fgb_size
    for seq in range(episodes):
        msg = episode_msg(config, seq)
        table.insert(msg_to_episode(msg), record=msg, waiter=_Ack())
        if (seq + 1) % every == 0:
            model = ClusterModel(version=(seq + 1) // every, n_goals=every, failures_seen=seq,
                                 centroids=rng.uniform(-1, 1, (config.cluster.k,
                                                               spec.goal_dim)))
            table.adopt_cluster_model(model, cluster_model_to_msg(model))
        if (seq + 1) % SCENE_FLUSH == 0 and log._writer is not None:
            log._writer.flush_scenes()
    if log._writer is not None:
        log._writer.flush_scenes()
    log.flush_upkeep()  # the numbered segments closed, as a running replay closes them
    sys.stdout.flush()
    os._exit(0)  # no close: the live segment stays as a SIGKILL leaves it


@dataclass
class KilledRun:
    """A run directory as a killed replay left it, and how to put it back so."""

    config: HercsConfig
    config_path: Path
    episodes: int
    files: dict[str, int]
    """Its log's files and their sizes, as left by the kill."""
    live_copy: Path
    """A copy of the unsealed live segment (recovery seals it in place)."""

    @property
    def run_dir(self) -> Path:
        return run_dir_of(self.config.run)

    def reset(self) -> None:
        """Back to the state the kill left: files a recovery added removed, the live segment
        unsealed again."""
        for path in segment_paths(self.run_dir):
            if path.name not in self.files or path.name == LIVE_NAME:
                path.unlink()
        if LIVE_NAME in self.files:
            shutil.copyfile(self.live_copy, RunDir(self.run_dir).episode_log)
        now = {p.name: p.stat().st_size for p in segment_paths(self.run_dir)}
        assert now == self.files, (now, self.files)


def write_killed_run(root: Path, *, transitions: int, endpoint: str, buffer: int | None,
                     extra: list[str]) -> KilledRun:
    config = run_config(root, endpoint=endpoint, buffer=buffer, extra=extra)
    config_path = RunDir(root).config
    save_yaml(config, config_path)
    episodes = transitions // T
    subprocess.run([sys.executable, "-m", "bench.faults.killed_replay_log",
                    str(config_path), str(episodes)], cwd=REPO, check=True)
    run_dir = run_dir_of(config.run)
    files = {p.name: p.stat().st_size for p in segment_paths(run_dir)}
    live_copy = root / "live-at-kill.mcap"
    if LIVE_NAME in files:
        shutil.copyfile(RunDir(run_dir).episode_log, live_copy)
    return KilledRun(config=config, config_path=config_path, episodes=episodes, files=files,
                     live_copy=live_copy)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.faults.killed_replay_log",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("config", type=Path, help="the run's config.yaml")
    parser.add_argument("episodes", type=int, help="episodes to insert before the kill")
    args = parser.parse_args(argv)
    return write_main(args.config, args.episodes)


if __name__ == "__main__":
    sys.exit(main())
