"""A replay's start: its episode log opened and replayed into a new table, so that nothing
acked is lost across a restart (docs/DESIGN.md §6, §8), and its newest cluster model adopted."""

from __future__ import annotations

import logging
from pathlib import Path

from hercs.config import HercsConfig
from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.replay_messages import cluster_model
from hercs.replay_service.table import ReplayTable
from hercs.rl.seeding import generator
from hercs.run.runlog import RecoveringLogWriter, read_cluster_models
from hercs.wire.codec import msg_to_episode, msg_to_replay_state

log = logging.getLogger("hercs.replay")


def open_table(config: HercsConfig, run_dir: Path) -> tuple[RecoveringLogWriter, ReplayTable]:
    """The run's episode log, open for appending, and a table holding what it logged."""
    replay, spec = config.replay, config.task.spec
    episode_log, recovered = RecoveringLogWriter.open(
        run_dir, run=config.run.name, task=spec.name, scene=replay.log_scene,
        segment_episodes=replay.log_segment_episodes(config.capacity_episodes),
        max_bytes=replay.log_max_bytes, spec=spec)
    saved = recovered.replay_state
    table = ReplayTable(config=config, rng=generator(config.run.seed, "replay"),
                        log=episode_log)
    count = 0

    def episodes():
        nonlocal count
        for episode_id, msg in recovered:
            count += 1
            yield episode_id, msg_to_episode(msg)

    state = None if saved is None else msg_to_replay_state(saved)
    for logged, stored in table.recover(episodes(), state=state):
        log.warning("recovered episode logged as id %d was stored as %d", logged, stored)
    if state is not None:
        log.info("started from the replay state the episode log saved at episode %d "
                 "(its buffer's oldest episode: %d)", state.next_episode_id,
                 state.first_held_id)
    if count:
        log.info("recovered %d acked episodes from the episode log", count)
        _restore_cluster_model(config, table, run_dir, saved)
    return episode_log, table


def _restore_cluster_model(config: HercsConfig, table: ReplayTable, run_dir: Path,
                           saved: pb.ReplayState | None) -> None:
    """The newest cluster model of the log (logged, or held by its saved replay state),
    so that a restarted replay samples by clusters at once even if no clusterer
    republishes its model."""
    models = list(read_cluster_models(run_dir))
    if saved is not None and saved.HasField("cluster_model"):
        models.append(saved.cluster_model)
    if not models:
        return
    last = max(models, key=lambda m: m.version)
    try:
        model = cluster_model(last, k=config.cluster.k, goal_dim=config.task.spec.goal_dim)
    except InvalidMessage as exc:
        log.warning("the log's last cluster model is not usable (%s); waiting for one", exc)
        return
    if table.adopt_cluster_model(model, None):
        log.info("cluster model v%d restored from the episode log", model.version)
