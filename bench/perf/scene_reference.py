"""The episode log's scene messages as they were built step by step until 2026-11-27 (bytes
per field with `hercs.wire.pbwire`, one message at a time): the reference that the vectorised
`hercs.run.runlog.scene_wire` must reproduce byte for byte (tests/unit/hercs/test_scene.py),
and the "before" side of `python -m bench.perf.inserts`. Not used by the log itself."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

from hercs.run.runlog import scene
from hercs.run.runlog.scene import EpisodePositions
from hercs.run.runlog.scene_wire import (  # the keys from the descriptors, shared
    _CLOUD_CONSTANT,
    _CLOUD_DATA,
    _CLOUD_TIMESTAMP,
    _CUBE_POSE,
    _ENTITY_CUBES,
    _ENTITY_METADATA,
    _ENTITY_SPHERES,
    _ENTITY_TIMESTAMP,
    _KEY_VALUE_VALUE,
    _POSE_ORIENTATION,
    _POSE_POSITION,
    _SPHERE_POSE,
    _STEP_KEY,
    _UPDATE_ENTITY,
    _points,
)
from hercs.wire import pbwire

_XYZ = pbwire.DoubleTriple(Vector3.DESCRIPTOR)


def _color(rgba: tuple[float, float, float, float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _size(edge: float) -> Vector3:
    return Vector3(x=edge, y=edge, z=edge)


def reference_scene_updates(positions: EpisodePositions, times_ns: Sequence[int], *,
                            goal_diameter: float, labels: dict[str, str]) -> list[bytes]:
    """One serialised `foxglove.SceneUpdate` per observation with entities `gripper`,
    `object` (if any) and `goal`, each replacing the previous step's entity of the same id;
    `labels` and the step index (`step`, last) become entity metadata.

    One message at a time (the reference; see the module docstring).
    """
    n = len(positions.gripper)
    if len(times_ns) != n:
        raise ValueError(f"{len(times_ns)} times for {n} observations")
    labels_metadata = [KeyValuePair(key=k, value=v) for k, v in labels.items()]

    def head(entity_id: str) -> bytes:
        return SceneEntity(frame_id=scene.FRAME_ID, id=entity_id,
                           metadata=labels_metadata).SerializeToString()

    def primitive(kind: type[SpherePrimitive] | type[CubePrimitive], edge: float,
                  rgba: tuple[float, float, float, float]) -> bytes:
        return kind(size=_size(edge), color=_color(rgba)).SerializeToString()

    # (constant head, primitive key, pose key, constant primitive per step, positions)
    entities: list[tuple[bytes, bytes, bytes, list[bytes], np.ndarray]] = [
        (head("gripper"), _ENTITY_SPHERES, _SPHERE_POSE,
         [primitive(SpherePrimitive, scene.GRIPPER_DIAMETER, scene.GRIPPER_RGBA)] * n,
         positions.gripper)]
    if positions.obj is not None:
        entities.append((head("object"), _ENTITY_CUBES, _CUBE_POSE,
                         [primitive(CubePrimitive, scene.OBJECT_SIZE, scene.OBJECT_RGBA)] * n,
                         positions.obj))
    reached = primitive(SpherePrimitive, goal_diameter, scene.GOAL_REACHED_RGBA)
    missed = primitive(SpherePrimitive, goal_diameter, scene.GOAL_MISSED_RGBA)
    entities.append((head("goal"), _ENTITY_SPHERES, _SPHERE_POSE,
                     [reached if r else missed for r in positions.reached.tolist()],
                     positions.goal))
    xyz = [body.astype(float).tolist() for *_, body in entities]  # per entity (T+1, 3)
    updates = []
    for t, time_ns in enumerate(times_ns):
        common = _ENTITY_TIMESTAMP.encode(int(time_ns)) + pbwire.length_delimited(
            _ENTITY_METADATA,
            _STEP_KEY + pbwire.length_delimited(_KEY_VALUE_VALUE, str(t).encode()))
        parts = []
        for (entity_head, primitive_key, pose_key, constant, _), rows in zip(
                entities, xyz, strict=True):
            pose = pbwire.length_delimited(
                pose_key, pbwire.length_delimited(_POSE_POSITION, _XYZ.pack(*rows[t]))
                + _POSE_ORIENTATION)
            parts.append(pbwire.length_delimited(_UPDATE_ENTITY, entity_head + common
                         + pbwire.length_delimited(primitive_key, pose + constant[t])))
        updates.append(b"".join(parts))
    return updates


def reference_point_clouds(positions: EpisodePositions, times_ns: Sequence[int]) -> list[bytes]:
    """One serialised `foxglove.PointCloud` per observation: points gripper, [object,] goal in
    that order, coloured as in `scene_updates` but opaque (the constant part serialised once,
    as there)."""
    n = len(positions.gripper)
    if len(times_ns) != n:
        raise ValueError(f"{len(times_ns)} times for {n} observations")
    points = _points(positions)  # the data are checked against protobuf in test_scene.py
    constant = _CLOUD_CONSTANT
    return [constant + _CLOUD_TIMESTAMP.encode(int(time_ns))
            + pbwire.length_delimited(_CLOUD_DATA, points[t].tobytes())
            for t, time_ns in enumerate(times_ns)]
