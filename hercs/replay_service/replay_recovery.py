"""A replay's start: its episode log opened and replayed into a new table, so that nothing
acked is lost across a restart (docs/DESIGN.md §6, §8), and its newest cluster model adopted."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from hercs.errors import InvalidMessage
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.replay_messages import cluster_model
from hercs.replay_service.table import ReplayTable
from hercs.rl.task_registry import TaskSpec
from hercs.run.runlog import RecoveringLogWriter, read_cluster_models
from hercs.wire.codec import msg_to_episode, msg_to_replay_state

log = logging.getLogger("hercs.replay")


def open_table(run_dir: Path, *, run: str, spec: TaskSpec, scene: bool, segment_episodes: int,
               max_bytes: int, new_table: Callable[[RecoveringLogWriter], ReplayTable]
               ) -> tuple[RecoveringLogWriter, ReplayTable]:
    """The run's episode log, open for appending, and a table holding what it logged.
    `new_table` makes the empty table that logs to it (`ReplayBuilder.open_table` passes its
    own); the other arguments say how the log is written (`replay.log_*`)."""
    episode_log, recovered = RecoveringLogWriter.open(
        run_dir, run=run, task=spec.name, scene=scene, segment_episodes=segment_episodes,
        max_bytes=max_bytes, spec=spec)
    saved = recovered.replay_state
    table = new_table(episode_log)
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
        _restore_cluster_model(table, run_dir, saved)
    return episode_log, table


def _restore_cluster_model(table: ReplayTable, run_dir: Path,
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
        model = cluster_model(last, k=table.clusters, goal_dim=table.spec.goal_dim)
    except InvalidMessage as exc:
        log.warning("the log's last cluster model is not usable (%s); waiting for one", exc)
        return
    if table.adopt_cluster_model(model, None):
        log.info("cluster model v%d restored from the episode log", model.version)
