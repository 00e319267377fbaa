"""Foxglove scene for one logged episode: gripper, object and goal per step.

Pure functions from an `Episode`'s arrays to the positions in `foxglove.SceneUpdate` (`/scene`)
and `foxglove.PointCloud` (`/scene/points`) messages, so `episodes.mcap` shows the episode in
3D without our code (docs/DESIGN.md §6): Foxglove draws the SceneUpdate (gripper sphere, 5 cm
object cube, a goal sphere twice the success threshold across, green while the achieved goal
is inside), which Rerun keeps raw; Rerun converts the PointCloud to `Points3D`. Positions are
in the MuJoCo world frame (metres, z up); beyond Fetch the moving body is the achieved goal's
first point, and a goal with no position part gets no scene. Times are offsets on the
synthetic timeline (the writer adds the run's start); the bytes come from
`hercs.run.runlog.scene_wire`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hercs.rl.task_registry import TaskSpec

STEP_NS = 40_000_000
"""Time between two observations: the Fetch control period, 0.04 s."""

FRAME_ID = "world"

GRIPPER_DIAMETER = 0.04
OBJECT_SIZE = 0.05  # the Fetch object is a 5 cm cube
GRIPPER_RGBA = (0.2, 0.45, 1.0, 1.0)
OBJECT_RGBA = (1.0, 0.6, 0.1, 1.0)
GOAL_REACHED_RGBA = (0.1, 0.85, 0.2, 0.35)
GOAL_MISSED_RGBA = (0.9, 0.1, 0.1, 0.35)


def episode_span_ns(episode_steps: int) -> int:
    """Length of one episode's window on the synthetic timeline: T+1 observations + one gap."""
    return (episode_steps + 2) * STEP_NS


def episode_start_ns(episode_id: int, episode_steps: int) -> int:
    return episode_id * episode_span_ns(episode_steps)


def step_times_ns(episode_id: int, n_steps: int, episode_steps: int) -> list[int]:
    """Synthetic log times of an episode's `n_steps` observations (n_steps ≤ T+1)."""
    if not 0 <= n_steps <= episode_steps + 1:
        raise ValueError(f"n_steps={n_steps}: an episode has at most T+1={episode_steps + 1} "
                         "observations on the timeline")
    start = episode_start_ns(episode_id, episode_steps)
    return [start + t * STEP_NS for t in range(n_steps)]


@dataclass(frozen=True)
class EpisodePositions:
    """Per-observation positions, each (T+1, 3) float32; `obj` is None for Reach."""

    gripper: np.ndarray
    obj: np.ndarray | None
    goal: np.ndarray
    reached: np.ndarray
    """(T+1,) bool: the achieved goal is within the success threshold of the goal."""


def episode_positions(obs: np.ndarray, ag: np.ndarray, g: np.ndarray,
                      spec: TaskSpec) -> EpisodePositions:
    """Gripper, object and goal at each of the T+1 observations; the goal of o_T is g[T-1].

    Fetch: gripper = obs[:, 0:3], object = obs[:, 3:6] (push, pick, slide; Reach has no
    object: its achieved goal is the gripper), goal = g."""
    if len(g) == 0:
        raise ValueError("an episode with no steps has no goal to show")
    full_goal = np.concatenate([g, g[-1:]], axis=0)
    if spec.gripper_position:
        gripper = np.asarray(obs[:, 0:3], dtype=np.float32)
        obj = np.asarray(obs[:, 3:6], dtype=np.float32) if spec.has_object else None
    else:  # beyond Fetch: the achieved goal's first point is the body that moves
        gripper, obj = goal_point(ag), None
    return EpisodePositions(gripper=gripper, obj=obj, goal=goal_point(full_goal),
                            reached=np.asarray(spec.is_success(ag, full_goal), bool))


def goal_point(goals: np.ndarray) -> np.ndarray:
    """The first 3-d position of each goal vector, (N, 3) float32: a 2-d goal (PointMaze)
    lies in the plane z = 0; a longer one starts with a position (hand tasks)."""
    goals = np.asarray(goals, dtype=np.float32)
    if goals.shape[-1] == 2:
        return np.concatenate([goals, np.zeros((*goals.shape[:-1], 1), np.float32)], axis=-1)
    return goals[..., :3]
