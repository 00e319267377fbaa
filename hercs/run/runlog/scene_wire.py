"""A whole episode's scene messages at once: the parts that change by step prepared together.

Each entity's fixed-width tail is one numpy row per step and the timestamps are encoded
together, so a message is one `bytes.join` of ~10 pieces instead of ~40 bytes operations (this
runs on the replay's core); the bytes equal the step-by-step
construction's (tests/unit/hercs/test_scene.py). A field's pieces parse in wire order, so the
step comes after the labels in `metadata`.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

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

from hercs.run.runlog.scene import (
    FRAME_ID,
    GOAL_MISSED_RGBA,
    GOAL_REACHED_RGBA,
    GRIPPER_DIAMETER,
    GRIPPER_RGBA,
    OBJECT_RGBA,
    OBJECT_SIZE,
    EpisodePositions,
)
from hercs.wire import pbwire
from hercs.wire.pbwire import varint

# Field keys of the parts that change from step to step (from the descriptors).
_LD = pbwire.LENGTH_DELIMITED
_UPDATE_ENTITY = pbwire.field_key(SceneUpdate.DESCRIPTOR, "entities", _LD)
_ENTITY_TIMESTAMP = pbwire.TimestampField(SceneEntity.DESCRIPTOR)
_ENTITY_METADATA = pbwire.field_key(SceneEntity.DESCRIPTOR, "metadata", _LD)
_ENTITY_SPHERES = pbwire.field_key(SceneEntity.DESCRIPTOR, "spheres", _LD)
_ENTITY_CUBES = pbwire.field_key(SceneEntity.DESCRIPTOR, "cubes", _LD)
_SPHERE_POSE = pbwire.field_key(SpherePrimitive.DESCRIPTOR, "pose", _LD)
_CUBE_POSE = pbwire.field_key(CubePrimitive.DESCRIPTOR, "pose", _LD)
_POSE_POSITION = pbwire.field_key(Pose.DESCRIPTOR, "position", _LD)
_POSE_ORIENTATION = pbwire.length_delimited(
    pbwire.field_key(Pose.DESCRIPTOR, "orientation", _LD),
    Quaternion(w=1.0).SerializeToString())
_KEY_VALUE_VALUE = pbwire.field_key(KeyValuePair.DESCRIPTOR, "value", _LD)
_STEP_KEY = KeyValuePair(key="step").SerializeToString()
_XYZ_KEYS = tuple(pbwire.field_key(Vector3.DESCRIPTOR, axis, pbwire.FIXED64)[0] for axis in "xyz")
_TRIPLE = np.dtype([("k0", "u1"), ("x", "<f8"), ("k1", "u1"), ("y", "<f8"),
                    ("k2", "u1"), ("z", "<f8")])
"""A Vector3 as three (key, double) fields, each written even when 0.0 (protobuf would
omit it; parsing gives the same message), packed: no padding."""
_XYZ_BYTES = _TRIPLE.itemsize
_POSE_LEN = len(_POSE_POSITION) + len(varint(_XYZ_BYTES)) + _XYZ_BYTES + len(_POSE_ORIENTATION)
"""A serialised Pose: its position (written per step) and orientation (constant)."""
_CLOUD_TIMESTAMP = pbwire.TimestampField(PointCloud.DESCRIPTOR)
_CLOUD_DATA = pbwire.field_key(PointCloud.DESCRIPTOR, "data", _LD)

_POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                         ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")])
_POINT_FIELDS = [
    PackedElementField(name=name, offset=field[1],
                       type=PackedElementField.FLOAT32 if name in "xyz"
                       else PackedElementField.UINT8)
    for name, field in (_POINT_DTYPE.fields or {}).items()
]
_CLOUD_CONSTANT = PointCloud(frame_id=FRAME_ID,
                             pose=Pose(position=Vector3(), orientation=Quaternion(w=1.0)),
                             point_stride=_POINT_DTYPE.itemsize,
                             fields=_POINT_FIELDS).SerializeToString()


_STEP_META: list[bytes] = []
"""The `step` metadata entry of step t, grown on demand (the same in every episode)."""


def _step_meta(n: int) -> list[bytes]:
    while len(_STEP_META) < n:
        value = pbwire.length_delimited(_KEY_VALUE_VALUE, str(len(_STEP_META)).encode())
        _STEP_META.append(pbwire.length_delimited(_ENTITY_METADATA, _STEP_KEY + value))
    return _STEP_META[:n]


@functools.lru_cache(maxsize=64)
def _primitive(kind: type[SpherePrimitive] | type[CubePrimitive], edge: float,
               rgba: tuple[float, float, float, float]) -> bytes:
    """A primitive's constant part: its size and colour (the pose is written per step)."""
    return kind(size=Vector3(x=edge, y=edge, z=edge),
                color=Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])).SerializeToString()


def _rows(parts: list[np.ndarray]) -> list[bytes]:
    """Per step, the concatenation of `parts` ((T+1, w) uint8 each, constants broadcast)."""
    rows = np.concatenate(parts, axis=1)
    data, width = rows.tobytes(), rows.shape[1]
    return [data[i:i + width] for i in range(0, len(data), width)]


def _tails(positions: EpisodePositions, goal_diameter: float) -> list[tuple[str, list[bytes]]]:
    """Per entity: (id, per step its primitive field: key, length, pose (position and
    orientation), then the constant size and colour)."""
    n = len(positions.gripper)

    def tail(primitive_key: bytes, pose_key: bytes, xyz: np.ndarray, constant: np.ndarray
             ) -> list[bytes]:
        triples = np.empty(n, dtype=_TRIPLE)
        triples["k0"], triples["k1"], triples["k2"] = _XYZ_KEYS
        triples["x"], triples["y"], triples["z"] = (xyz[:, i] for i in range(3))
        pose_head = pose_key + varint(_POSE_LEN) + _POSE_POSITION + varint(_XYZ_BYTES)
        width = len(pose_key) + len(varint(_POSE_LEN)) + _POSE_LEN + constant.shape[1]
        return _rows([constant_rows(primitive_key + varint(width) + pose_head, n),
                      triples.view(np.uint8).reshape(n, -1),
                      constant_rows(_POSE_ORIENTATION, n), constant])

    reached = _primitive(SpherePrimitive, goal_diameter, GOAL_REACHED_RGBA)
    missed = _primitive(SpherePrimitive, goal_diameter, GOAL_MISSED_RGBA)
    if len(reached) != len(missed):  # both colours have all four channels non-zero
        raise ValueError("the goal's two colours must serialise to the same width")
    goal = np.where(positions.reached[:, None], np.frombuffer(reached, np.uint8),
                    np.frombuffer(missed, np.uint8))
    sphere = _primitive(SpherePrimitive, GRIPPER_DIAMETER, GRIPPER_RGBA)
    tails = [("gripper", tail(_ENTITY_SPHERES, _SPHERE_POSE, positions.gripper,
                              constant_rows(sphere, n)))]
    if positions.obj is not None:
        cube = _primitive(CubePrimitive, OBJECT_SIZE, OBJECT_RGBA)
        tails.append(("object", tail(_ENTITY_CUBES, _CUBE_POSE, positions.obj,
                                     constant_rows(cube, n))))
    tails.append(("goal", tail(_ENTITY_SPHERES, _SPHERE_POSE, positions.goal, goal)))
    return tails


def scene_updates(positions: EpisodePositions, times_ns: Sequence[int], *,
                  goal_diameter: float, labels: dict[str, str]) -> list[bytes]:
    """One serialised `foxglove.SceneUpdate` per observation with entities `gripper`,
    `object` (if any) and `goal`, each replacing the previous step's entity of the same id;
    `labels` and the step index (`step`, last) become entity metadata."""
    n = len(positions.gripper)
    if len(times_ns) != n:
        raise ValueError(f"{len(times_ns)} times for {n} observations")
    metadata = [KeyValuePair(key=k, value=v) for k, v in labels.items()]
    commons = [stamp + meta for stamp, meta in zip(
        _ENTITY_TIMESTAMP.encode_many(times_ns), _step_meta(n), strict=True)]
    common_widths = [len(c) for c in commons]
    # per entity: its field key, length and head, by the common part's width; tail per step
    entities = []
    for entity_id, tails in _tails(positions, goal_diameter):
        head = SceneEntity(frame_id=FRAME_ID, id=entity_id,
                           metadata=metadata).SerializeToString()
        fixed = len(head) + len(tails[0])  # every step's tail has the same width
        entities.append(({w: _UPDATE_ENTITY + varint(fixed + w) + head
                          for w in set(common_widths)}, tails))
    (p0, t0), *rest = entities
    if len(rest) == 2:  # Fetch with an object: three entities (the common case, unrolled)
        (p1, t1), (p2, t2) = rest
        return [b"".join((p0[w], c, a, p1[w], c, b, p2[w], c, d)) for c, w, a, b, d in zip(
            commons, common_widths, t0, t1, t2, strict=True)]
    return [b"".join(piece for prefixes, tails in entities
                     for piece in (prefixes[w], c, tails[t]))
            for t, (c, w) in enumerate(zip(commons, common_widths, strict=True))]


def constant_rows(data: bytes, k: int) -> np.ndarray:
    """(k, len(data)) uint8, every row `data` (a broadcast view)."""
    return np.broadcast_to(np.frombuffer(data, np.uint8), (k, len(data)))


def _rgba8(rgba: tuple[float, float, float, float]) -> np.ndarray:
    """Opaque 8-bit colour."""
    return np.round(np.array([*rgba[:3], 1.0]) * 255).astype(np.uint8)


def _points(positions: EpisodePositions) -> np.ndarray:
    """(T+1, P * 16) uint8: each observation's points as `PointCloud.data`."""
    n = len(positions.gripper)
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
    return points.view(np.uint8).reshape(n, -1)


def point_clouds(positions: EpisodePositions, times_ns: Sequence[int]) -> list[bytes]:
    """One serialised `foxglove.PointCloud` per observation: points gripper, [object,] goal in
    that order, coloured as in `scene_updates` but opaque (the constant part serialised once)."""
    n = len(positions.gripper)
    if len(times_ns) != n:
        raise ValueError(f"{len(times_ns)} times for {n} observations")
    points = _points(positions)
    tails = _rows([constant_rows(_CLOUD_DATA + varint(points.shape[1]), n), points])
    return [b"".join((_CLOUD_CONSTANT, stamp, tail)) for stamp, tail in zip(
        _CLOUD_TIMESTAMP.encode_many(times_ns), tails, strict=True)]
