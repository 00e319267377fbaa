"""The episode log's scene messages, built as bytes, against the messages protobuf builds
from the same positions (an independent construction, field by field)."""

import numpy as np
import pytest
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

from bench.perf.scene_reference import reference_point_clouds, reference_scene_updates
from hercs.rl.task_registry import TaskSpec, task_spec
from hercs.run.runlog import scene, scene_wire

LABELS = {"episode_id": "7", "actor_id": "actor-0", "seq": "3", "success": "false"}


def positions_of(task: str, rng: np.random.Generator) -> scene.EpisodePositions:
    spec = task_spec(task)
    T = spec.episode_steps
    obs = rng.uniform(-2, 2, size=(T + 1, spec.obs_dim)).astype(np.float32)
    obs[0, 0:6] = 0.0  # a coordinate at exactly 0.0 (protobuf would omit it)
    g = np.repeat(rng.uniform(-2, 2, size=(1, spec.goal_dim)), T, axis=0).astype(np.float32)
    ag = obs[1:, 3:6] if spec.has_object else obs[1:, 0:3]
    ag = np.concatenate([obs[:1, 0:3], ag], axis=0)
    ag[5] = g[0]  # step 5 inside the goal: the goal is drawn green there
    return scene.episode_positions(obs, ag, g, spec)


def expected_update(p: scene.EpisodePositions, t: int, time_ns: int,
                    goal_diameter: float) -> SceneUpdate:
    def entity(entity_id: str, xyz: np.ndarray, **primitive: object) -> SceneEntity:
        e = SceneEntity(frame_id="world", id=entity_id,
                        metadata=[*(KeyValuePair(key=k, value=v) for k, v in LABELS.items()),
                                  KeyValuePair(key="step", value=str(t))], **primitive)
        e.timestamp.FromNanoseconds(time_ns)
        return e

    def pose(xyz: np.ndarray) -> Pose:
        x, y, z = (float(v) for v in xyz)
        return Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(w=1.0))

    def color(rgba: tuple[float, float, float, float]) -> Color:
        return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])

    def cube(edge: float) -> Vector3:
        return Vector3(x=edge, y=edge, z=edge)

    entities = [entity("gripper", p.gripper[t], spheres=[SpherePrimitive(
        pose=pose(p.gripper[t]), size=cube(scene.GRIPPER_DIAMETER),
        color=color(scene.GRIPPER_RGBA))])]
    if p.obj is not None:
        entities.append(entity("object", p.obj[t], cubes=[CubePrimitive(
            pose=pose(p.obj[t]), size=cube(scene.OBJECT_SIZE), color=color(scene.OBJECT_RGBA))]))
    goal_rgba = scene.GOAL_REACHED_RGBA if p.reached[t] else scene.GOAL_MISSED_RGBA
    entities.append(entity("goal", p.goal[t], spheres=[SpherePrimitive(
        pose=pose(p.goal[t]), size=cube(goal_diameter), color=color(goal_rgba))]))
    return SceneUpdate(entities=entities)


@pytest.mark.parametrize("task", ["reach", "push"])
def test_scene_updates_parse_as_the_messages(task: str) -> None:
    p = positions_of(task, np.random.default_rng(3))
    assert p.reached[5] and not p.reached.all()
    start = 1_764_000_000_123_456_789  # a real epoch time in ns: seconds and nanos both set
    times = [start + t * scene.STEP_NS for t in range(len(p.gripper))]
    updates = scene_wire.scene_updates(p, times, goal_diameter=0.1, labels=LABELS)
    assert len(updates) == len(times)
    for t, data in enumerate(updates):
        assert SceneUpdate.FromString(data) == expected_update(p, t, times[t], 0.1), t


def test_point_clouds_parse_as_the_messages() -> None:
    p = positions_of("push", np.random.default_rng(4))
    times = [t * scene.STEP_NS for t in range(len(p.gripper))]  # from 0: seconds 0 at first
    clouds = scene_wire.point_clouds(p, times)
    for t, data in enumerate(clouds):
        cloud = PointCloud.FromString(data)
        assert cloud.frame_id == "world" and cloud.pose.orientation.w == 1.0
        assert cloud.timestamp.ToNanoseconds() == times[t]
        points = np.frombuffer(cloud.data, dtype=[("xyz", "<f4", 3), ("rgba", "u1", 4)])
        assert cloud.point_stride == points.dtype.itemsize == 16
        np.testing.assert_array_equal(points["xyz"], np.stack([p.gripper[t], p.obj[t],
                                                               p.goal[t]]))
        goal_rgb = points["rgba"][2, :3]
        expected = scene.GOAL_REACHED_RGBA if p.reached[t] else scene.GOAL_MISSED_RGBA
        np.testing.assert_array_equal(goal_rgb,
                                      np.round(np.array(expected[:3]) * 255).astype(np.uint8))


def test_times_must_match_the_observations() -> None:
    p = positions_of("push", np.random.default_rng(5))
    with pytest.raises(ValueError, match="50 times for 51 observations"):
        scene_wire.scene_updates(p, list(range(50)), goal_diameter=0.1, labels=LABELS)
    with pytest.raises(ValueError, match="50 times for 51 observations"):
        scene_wire.point_clouds(p, list(range(50)))


@pytest.mark.parametrize("task", ["PointMaze_UMaze-v3", "HandReach-v3", "HandManipulateBlock-v1"])
def test_beyond_fetch_the_body_is_the_achieved_goals_first_point(task: str) -> None:
    """No gripper in the observation: the scene draws the achieved goal's first 3-d point
    (a 2-d goal in the plane z = 0) and the desired goal's, and judges by the task's rule."""
    spec = task_spec(task)
    T, rng = spec.episode_steps, np.random.default_rng(4)
    obs = rng.normal(size=(T + 1, spec.obs_dim)).astype(np.float32)
    g = np.repeat(rng.normal(size=(1, spec.goal_dim)), T, axis=0).astype(np.float32)
    ag = g[0] + rng.uniform(2.0, 3.0, size=(T + 1, spec.goal_dim)).astype(np.float32)
    if spec.goal_dim == 7:  # unit quaternions
        g[:, 3:] /= np.linalg.norm(g[0, 3:])
        ag[:, 3:] /= np.linalg.norm(ag[:, 3:], axis=1, keepdims=True)
    ag[3] = g[0]  # reached at step 3 only
    p = scene.episode_positions(obs, ag, g, spec)
    assert p.obj is None
    assert p.gripper.shape == p.goal.shape == (T + 1, 3)
    if spec.goal_dim == 2:
        np.testing.assert_array_equal(p.gripper[:, :2], ag)
        assert not p.gripper[:, 2].any() and not p.goal[:, 2].any()
    else:
        np.testing.assert_array_equal(p.gripper, ag[:, :3])
    np.testing.assert_array_equal(p.goal[:T], g[:, :3] if spec.goal_dim > 2 else p.goal[:T])
    assert p.reached.tolist() == [t == 3 for t in range(T + 1)]


@pytest.mark.parametrize("task", ["push", "reach", "PointMaze_UMaze-v3"])
@pytest.mark.parametrize("start", [0, 127, 4_920_000_000, 1_764_000_000_123_456_789])
def test_the_same_bytes_as_the_step_by_step_construction(task: str, start: int) -> None:
    """scene_wire prepares the changing parts for the whole episode at once; every message is
    the byte string the step-by-step reference builds (starts put varint widths across steps:
    nanos of 0, 1 and 5 bytes, seconds of 0 and 5 bytes, steps of one and two digits)."""
    spec = task_spec(task)
    p = (positions_of(task, np.random.default_rng(6)) if spec.gripper_position
         else scene.episode_positions(*_maze_arrays(spec), spec))
    times = [start + t * scene.STEP_NS for t in range(len(p.gripper))]
    assert scene_wire.scene_updates(p, times, goal_diameter=0.1, labels=LABELS) == \
        reference_scene_updates(p, times, goal_diameter=0.1, labels=LABELS)
    assert scene_wire.point_clouds(p, times) == reference_point_clouds(p, times)


def _maze_arrays(spec: TaskSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng, T = np.random.default_rng(7), spec.episode_steps
    g = np.repeat(rng.normal(size=(1, spec.goal_dim)), T, axis=0).astype(np.float32)
    ag = rng.normal(size=(T + 1, spec.goal_dim)).astype(np.float32)
    ag[2] = g[0]
    return rng.normal(size=(T + 1, spec.obs_dim)).astype(np.float32), ag, g
