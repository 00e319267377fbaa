"""Foxglove scene messages for one logged episode: gripper, object and goal per step.

Pure functions from an `Episode`'s arrays to Foxglove protobuf messages, so that
`episodes.mcap` shows the episode in 3D without our code:

- `foxglove.SceneUpdate` (topic `/scene`): the gripper as a sphere, the object as a 5 cm cube,
  the goal as a translucent sphere whose diameter is twice the success threshold (green while
  the achieved goal is inside it, red otherwise). Foxglove's 3D panel draws these; Rerun 0.41's
  MCAP importer does not convert SceneUpdate (it keeps the raw message).
- `foxglove.PointCloud` (topic `/scene/points`): the same positions as one coloured point each.
  Rerun's importer converts it to `Points3D` (with colours) and Foxglove draws it too.

Positions are in the MuJoCo world frame (metres, z up), frame id `world`: gripper =
obs[:, 0:3], object = obs[:, 3:6] (push, pick, slide; Reach has no object: its achieved goal
is the gripper), goal = g (T rows; the final observation o_T shows the last goal).

Timeline (synthetic, so that episodes never overlap in a viewer): episode k occupies
[k·span, k·span + T·40 ms] with span = (T + 2)·40 ms, i.e. its T+1 observations 40 ms apart
(the Fetch control period, docs/DESIGN.md §4 Δt) and one empty 40 ms slot before episode k+1.
The functions here give offsets from 0; the writer adds the run's start time (ns since the
Unix epoch, `hercs.runlog.format`), so a viewer's clock starts when the run started.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

from hercs.tasks import TaskSpec

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
    """Gripper, object and goal at each of the T+1 observations; the goal of o_T is g[T-1]."""
    if len(g) == 0:
        raise ValueError("an episode with no steps has no goal to show")
    goal = np.concatenate([g, g[-1:]], axis=0).astype(np.float32, copy=False)
    obj = obs[:, 3:6] if spec.has_object else None
    return EpisodePositions(
        gripper=np.asarray(obs[:, 0:3], dtype=np.float32),
        obj=None if obj is None else np.asarray(obj, dtype=np.float32),
        goal=goal,
        reached=spec.is_success(ag, goal),
    )


def _pose(p: np.ndarray) -> Pose:
    return Pose(position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                orientation=Quaternion(w=1.0))


def _color(rgba: tuple[float, float, float, float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _size(edge: float) -> Vector3:
    return Vector3(x=edge, y=edge, z=edge)


def scene_updates(positions: EpisodePositions, times_ns: Sequence[int], *,
                  goal_diameter: float, labels: dict[str, str]) -> list[SceneUpdate]:
    """One SceneUpdate per observation with entities `gripper`, `object` (if any) and `goal`,
    each replacing the previous step's entity of the same id; `labels` and the step index
    become entity metadata.

    Built by copying one template update and setting positions, time, step and goal colour
    (about 3x faster than constructing each message: this runs on the replay's insert path).
    """
    n = len(positions.gripper)
    if len(times_ns) != n:
        raise ValueError(f"{len(times_ns)} times for {n} observations")
    metadata = [*(KeyValuePair(key=k, value=v) for k, v in labels.items()),
                KeyValuePair(key="step", value="")]
    origin = _pose(np.zeros(3))
    template = SceneUpdate(entities=[SceneEntity(
        frame_id=FRAME_ID, id="gripper", metadata=metadata,
        spheres=[SpherePrimitive(pose=origin, size=_size(GRIPPER_DIAMETER),
                                 color=_color(GRIPPER_RGBA))])])
    bodies = [positions.gripper]
    if positions.obj is not None:
        template.entities.append(SceneEntity(
            frame_id=FRAME_ID, id="object", metadata=metadata,
            cubes=[CubePrimitive(pose=origin, size=_size(OBJECT_SIZE),
                                 color=_color(OBJECT_RGBA))]))
        bodies.append(positions.obj)
    template.entities.append(SceneEntity(
        frame_id=FRAME_ID, id="goal", metadata=metadata,
        spheres=[SpherePrimitive(pose=origin, size=_size(goal_diameter))]))
    bodies.append(positions.goal)
    xyz = np.stack(bodies, axis=1).astype(float).tolist()  # (T+1, entities, 3) as floats
    reached_color, missed_color = _color(GOAL_REACHED_RGBA), _color(GOAL_MISSED_RGBA)
    updates = []
    for t, time_ns in enumerate(times_ns):
        update = SceneUpdate()
        update.CopyFrom(template)
        for entity, p in zip(update.entities, xyz[t], strict=True):
            primitive = entity.cubes[0] if entity.cubes else entity.spheres[0]
            position = primitive.pose.position
            position.x, position.y, position.z = p
            entity.timestamp.FromNanoseconds(time_ns)
            entity.metadata[-1].value = str(t)
        update.entities[-1].spheres[0].color.CopyFrom(
            reached_color if positions.reached[t] else missed_color)
        updates.append(update)
    return updates


_POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                         ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")])
_POINT_FIELDS = [
    PackedElementField(name=name, offset=field[1],
                       type=PackedElementField.FLOAT32 if name in "xyz"
                       else PackedElementField.UINT8)
    for name, field in (_POINT_DTYPE.fields or {}).items()
]


def _rgba8(rgba: tuple[float, float, float, float]) -> np.ndarray:
    """Opaque 8-bit colour (a point cloud has no use for translucency)."""
    return np.round(np.array([*rgba[:3], 1.0]) * 255).astype(np.uint8)


def point_clouds(positions: EpisodePositions, times_ns: Sequence[int]) -> list[PointCloud]:
    """One PointCloud per observation: points gripper, [object,] goal in that order, coloured
    as in `scene_updates` but opaque."""
    n = len(positions.gripper)
    if len(times_ns) != n:
        raise ValueError(f"{len(times_ns)} times for {n} observations")
    bodies = [positions.gripper, positions.goal]
    palette = [_rgba8(GRIPPER_RGBA), _rgba8(GOAL_MISSED_RGBA)]
    if positions.obj is not None:
        bodies.insert(1, positions.obj)
        palette.insert(1, _rgba8(OBJECT_RGBA))
    xyz = np.stack(bodies, axis=1)                               # (T+1, P, 3)
    rgba = np.repeat(np.stack(palette)[None], n, axis=0)         # (T+1, P, 4)
    rgba[positions.reached, -1] = _rgba8(GOAL_REACHED_RGBA)
    points = np.empty(xyz.shape[:2], dtype=_POINT_DTYPE)
    for i, axis in enumerate("xyz"):
        points[axis] = xyz[..., i]
    for i, channel in enumerate(("red", "green", "blue", "alpha")):
        points[channel] = rgba[..., i]
    identity = Pose(position=Vector3(), orientation=Quaternion(w=1.0))
    clouds = []
    for t, time_ns in enumerate(times_ns):
        cloud = PointCloud(frame_id=FRAME_ID, pose=identity, point_stride=_POINT_DTYPE.itemsize,
                           fields=_POINT_FIELDS, data=points[t].tobytes())
        cloud.timestamp.FromNanoseconds(time_ns)
        clouds.append(cloud)
    return clouds
