"""Rerun drawing shared by `hercs view` and the live view: the episode, cluster and curve
entities, their colours and the default layout, so a live recording and a later one look alike.

Every function takes the `rerun` module (`rr`, imported by callers only when recording, so
`hercs --help` stays fast) and a `RecordingStream` (`rec`); none reads a file or talks to Zenoh.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hercs.proto import hercs_pb2 as pb
from hercs.rl.cluster_model import ClusterModel, assign_clusters
from hercs.rl.task_registry import TaskSpec
from hercs.run.runlog.scene import episode_positions, goal_point
from hercs.wire.codec import msg_to_array

APP_ID = "hercs"

# tab10: one colour per cluster (index modulo 10).
PALETTE = np.array([
    [31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
    [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207],
], dtype=np.uint8)
UNCLUSTERED = (170, 170, 170)
SUCCESS_RGBA = (30, 200, 60, 160)
FAILURE_RGBA = (220, 30, 30, 160)

# Radii in ui points (the same size on screen at any zoom): hundreds of goals a few
# centimetres apart, drawn as spheres of a world size, hid the table and one another, and
# paths centimetres wide near the camera hid the centroids. The centroids, k of them, are
# the large marks.
CENTROID_POINTS = 10.0
FAILED_GOAL_POINTS = 1.5
GOAL_POINTS = 3.0
OBJECT_PATH_POINTS = 1.25
GRIPPER_PATH_POINTS = 0.75


# --------------------------------------------------------------------------------------------
# What is drawn


@dataclass
class EpisodeOutcome:
    """What every episode contributes (the per-episode scalars and the failed goals); the
    live view has it from the replay's EpisodeHeader alone."""

    episode_id: int
    success: bool  # ‖ag_T − g_T‖ ≤ the task's threshold
    final_distance: float
    cluster: int  # of ag_T under the cluster model current at insert; −1 before the first
    desired_goal: np.ndarray  # g_T, (goal_dim,)
    actor_id: str
    seq: int
    policy_version: int
    # wall-clock time the replay logged it (ns since the epoch); 0 unknown (live view)
    inserted_ns: int = field(default=0, kw_only=True)


@dataclass
class EpisodeSummary(EpisodeOutcome):
    """An outcome plus the positions drawn in 3D (selected episodes)."""

    gripper: np.ndarray  # (T+1, 3)
    obj: np.ndarray | None  # (T+1, 3)
    goal: np.ndarray  # (T+1, 3): g, with g[T-1] repeated for o_T


@dataclass
class LoggedModel:
    """A cluster model and the id of the first episode it applies to."""

    at_episode: int
    model: ClusterModel


def summarize_episode(msg: pb.Episode, *, episode_id: int, spec: TaskSpec,
                      cluster: int) -> EpisodeSummary:
    """An Episode message as drawn: the positions the episode log's scene shows
    (`hercs.run.runlog.scene.episode_positions`: gripper and object for Fetch, the achieved
    goal's first point beyond it), success by the task's rule (`TaskSpec.is_success`)."""
    obs = msg_to_array(msg.obs, where="Episode.obs")
    ag = msg_to_array(msg.ag, where="Episode.ag")
    g = msg_to_array(msg.g, where="Episode.g")
    distance = float(np.linalg.norm(ag[-1] - g[-1]))
    positions = episode_positions(obs, ag, g, spec)
    return EpisodeSummary(
        episode_id=episode_id, success=bool(spec.is_success(ag[-1], g[-1])),
        final_distance=distance, cluster=cluster, desired_goal=np.asarray(g[-1]),
        actor_id=msg.actor_id, seq=int(msg.seq), policy_version=int(msg.policy_version),
        gripper=positions.gripper, obj=positions.obj, goal=positions.goal)


# --------------------------------------------------------------------------------------------
# Drawing


def log_world(rr, rec) -> None:
    """The static world frame: right-handed, z up (MuJoCo world, metres)."""
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)


def cluster_colors(clusters: np.ndarray, alpha: int = 255) -> np.ndarray:
    """(N, 4) uint8 RGBA: the palette colour of each cluster index, grey for −1."""
    clusters = np.asarray(clusters, dtype=np.int64)
    rgb = np.where((clusters < 0)[:, None], np.array(UNCLUSTERED, np.uint8),
                   PALETTE[np.maximum(clusters, 0) % len(PALETTE)])
    return np.concatenate([rgb, np.full((len(clusters), 1), alpha, np.uint8)], axis=1)


def _growing_strips(rr, rec, entity: str, episode_id: int, path: np.ndarray,
                    color: np.ndarray, radius: float) -> None:
    n = len(path)
    rec.send_columns(
        entity,
        indexes=[rr.TimeColumn("step", sequence=np.arange(n)),
                 rr.TimeColumn("episode", sequence=np.full(n, episode_id))],
        columns=rr.LineStrips3D.columns(strips=[path[:t + 1] for t in range(n)],
                                        colors=np.repeat(color[None], n, axis=0),
                                        radii=np.full(n, radius, np.float32)),
    )


def log_episode(rr, rec, ep: EpisodeSummary) -> None:
    base = f"world/episodes/{ep.episode_id:06d}"
    color = cluster_colors(np.array([ep.cluster]))[0]
    if ep.obj is not None:
        _growing_strips(rr, rec, f"{base}/object", ep.episode_id, ep.obj, color,
                        rr.Radius.ui_points(OBJECT_PATH_POINTS))
        gripper_color = color.copy()
        gripper_color[3] = 110
    else:
        gripper_color = color
    _growing_strips(rr, rec, f"{base}/gripper", ep.episode_id, ep.gripper, gripper_color,
                    rr.Radius.ui_points(GRIPPER_PATH_POINTS))
    n = len(ep.goal)
    rec.send_columns(
        f"{base}/goal",
        indexes=[rr.TimeColumn("step", sequence=np.arange(n)),
                 rr.TimeColumn("episode", sequence=np.full(n, ep.episode_id))],
        columns=rr.Points3D.columns(
            positions=ep.goal,
            colors=np.repeat(np.array([SUCCESS_RGBA if ep.success else FAILURE_RGBA],
                                      np.uint8), n, axis=0),
            radii=np.full(n, rr.Radius.ui_points(GOAL_POINTS), np.float32)),
    )
    rec.set_time("episode", sequence=ep.episode_id)
    outcome = "success" if ep.success else "FAILED"
    cluster = "-" if ep.cluster < 0 else str(ep.cluster)
    rec.log("log/episodes", rr.TextLog(
        f"episode {ep.episode_id}: {outcome}, |ag_T - g_T| = {ep.final_distance:.3f} m, "
        f"cluster {cluster}, actor {ep.actor_id} seq {ep.seq}, policy v{ep.policy_version}",
        level=rr.TextLogLevel.INFO if ep.success else rr.TextLogLevel.WARN))


def log_episode_scalars(rr, rec, episodes: Sequence[EpisodeOutcome], *,
                        styles: bool = True) -> None:
    """`episodes/success`, `episodes/final_distance`, `episodes/cluster` on `episode`, one
    row per episode, also on the wall-clock `time` timeline when every episode's insert time
    is known; `styles=False` skips the static series styles (logged once is enough)."""
    indexes = [rr.TimeColumn("episode", sequence=[e.episode_id for e in episodes])]
    if episodes and all(e.inserted_ns > 0 for e in episodes):
        indexes.append(rr.TimeColumn("time", timestamp=np.array(
            [e.inserted_ns for e in episodes], dtype="datetime64[ns]")))
    for name, values in (("success", [float(e.success) for e in episodes]),
                         ("final_distance", [e.final_distance for e in episodes]),
                         ("cluster", [float(e.cluster) for e in episodes])):
        if styles:
            style = (rr.SeriesLines(names=name) if name == "final_distance"
                     else rr.SeriesPoints(names=name, marker_sizes=1.5))
            rec.log(f"episodes/{name}", style, static=True)
        rec.send_columns(f"episodes/{name}", indexes=indexes,
                         columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)))


def log_centroids(rr, rec, logged: LoggedModel) -> None:
    """`world/centroids` and a `log/cluster_models` line at the model's first episode."""
    model = logged.model
    rec.set_time("episode", sequence=logged.at_episode)
    k = model.k
    rec.log("world/centroids", rr.Points3D(
        goal_point(model.centroids), colors=cluster_colors(np.arange(k)),
        radii=np.full(k, rr.Radius.ui_points(CENTROID_POINTS), np.float32),
        labels=[f"c{i}" for i in range(k)], show_labels=True))  # the only labelled points
    rec.log("log/cluster_models", rr.TextLog(
        f"cluster model v{model.version}: k={k}, fitted on {model.n_goals} failed goals "
        f"({model.failures_seen} seen), applies from episode {logged.at_episode}"))


def log_failed_goals(rr, rec, *, at_episode: int, goals: np.ndarray,
                     centroids: np.ndarray | None) -> None:
    """`world/failed_goals` at `at_episode`: `goals` (N, goal_dim) coloured by their nearest
    centroid (grey without a model), drawn at their first 3-d point (`goal_point`)."""
    if centroids is not None and len(goals):
        colors = cluster_colors(assign_clusters(goals, centroids), 200)
    else:
        colors = cluster_colors(np.full(len(goals), -1), 200)
    rec.set_time("episode", sequence=at_episode)
    points = goal_point(goals) if len(goals) else np.zeros((0, 3), np.float32)
    rec.log("world/failed_goals", rr.Points3D(
        points, colors=colors, radii=np.full(len(goals), rr.Radius.ui_points(FAILED_GOAL_POINTS),
                                      np.float32)))


def declare_curve(rr, rec, name: str) -> str:
    """Log the static series style of `curves/<name>` and return that entity path."""
    entity = f"curves/{name}"
    rec.log(entity, rr.SeriesLines(names=name), static=True)
    return entity


def rerun_executable() -> str | None:
    """The `rerun` beside this interpreter (the pinned rerun-sdk's), else None: rerun-sdk then
    looks for one on PATH."""
    rerun_exe = Path(sys.executable).parent / "rerun"
    return str(rerun_exe) if rerun_exe.exists() else None
