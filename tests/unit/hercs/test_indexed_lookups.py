"""The indexed reads of a gymnasium-robotics env (hercs/rl/indexed_lookups.py) change no bit:
observations, rewards and infos equal the module's own, step for step, through resets."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.rl.envs import make_env
from hercs.rl.indexed_lookups import IndexedMujocoUtils, index_lookups
from hercs.rl.task_registry import task_spec
from tests.support import skip_without_mujoco_py


def _same(a: object, b: object) -> bool:
    """Equal to the bit, dtypes and shapes included (dicts of arrays, arrays, scalars)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, tuple):
        return (isinstance(b, tuple) and len(a) == len(b)
                and all(_same(x, y) for x, y in zip(a, b, strict=True)))
    if isinstance(a, np.ndarray):
        return (isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
                and a.tobytes() == b.tobytes())
    return type(a) is type(b) and a == b


@pytest.mark.parametrize("task", ["reach", "push", "slide", "pick", "HandReach-v3",
                                  "HandManipulatePenRotate-v1"])
def test_indexed_reads_are_bit_identical_to_the_modules(task: str) -> None:
    spec = task_spec(task)
    by_name, indexed = make_env(spec, indexed=False), make_env(spec)
    assert not isinstance(by_name.unwrapped._utils, IndexedMujocoUtils)
    assert isinstance(indexed.unwrapped._utils, IndexedMujocoUtils)
    rng = np.random.default_rng(7)
    try:
        for episode, seed in enumerate((11, None, None)):
            assert _same(by_name.reset(seed=seed), indexed.reset(seed=seed)), episode
            for step in range(spec.episode_steps):
                action = rng.uniform(-1.0, 1.0, spec.action_dim).astype(np.float32)
                assert _same(by_name.step(action), indexed.step(action)), (episode, step)
        # the robot's joints and the sites were read by address, not handed back to the module
        reader = indexed.unwrapped._utils
        assert reader._robot_joints is not None and reader._robot_joints[1].size >= 2
        if spec.family == "fetch":
            assert "robot0:grip" in reader._site_ids
        if task in ("reach", "push", "slide"):  # fingers blocked every step: slide joints
            written = reader._one_coordinate_qpos  # and the object's free joint, by the module
            assert all(written[f"robot0:{side}_gripper_finger_joint"] is not None
                       for side in "lr"), written
    finally:
        by_name.close()
        indexed.close()


MODEL = """
<mujoco>
  <worldbody>
    <body name="box" pos="0 0 1"><freejoint name="box:joint"/><geom size=".1"/></body>
    <body name="arm">
      <joint name="robot0:ball" type="ball"/><geom size=".1" pos=".2 0 0"/>
      <body name="forearm">
        <joint name="robot0:slide" type="slide"/>
        <joint name="robot0:hinge_a" type="hinge"/><joint name="robot0:hinge_b" type="hinge"/>
        <geom size=".1" pos=".4 0 0"/><site name="tip" pos=".5 0 0"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
"""qpos and qvel addresses differ (a free joint first) and a ball joint is among the robot's."""


def _model_and_data(seed: int):  # type: ignore[no-untyped-def]
    import mujoco

    model = mujoco.MjModel.from_xml_string(MODEL)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    data.qpos[:] = rng.standard_normal(model.nq)
    data.qvel[:] = rng.standard_normal(model.nv)
    mujoco.mj_forward(model, data)
    return model, data


def test_a_model_whose_qpos_and_qvel_addresses_differ_reads_the_same() -> None:
    from gymnasium_robotics.utils import mujoco_utils

    model, data = _model_and_data(0)
    reader = IndexedMujocoUtils(mujoco_utils)
    hinges = ("robot0:slide", "robot0:hinge_a", "robot0:hinge_b")
    for names in (hinges, ("box:joint", *hinges[::-1]), ("robot0:hinge_a",)):
        # one-coordinate joints by address (non-robot names skipped); fewer than two: the module
        assert _same(reader.robot_get_obs(model, data, names),
                     mujoco_utils.robot_get_obs(model, data, names)), names
    assert reader._robot_joints is not None and reader._robot_joints[1].size == 0
    with_ball = ("robot0:ball", *hinges)  # the module's own error: rows of 4 and of 1
    with pytest.raises(ValueError, match="inhomogeneous"):
        mujoco_utils.robot_get_obs(model, data, with_ball)
    with pytest.raises(ValueError, match="inhomogeneous"):
        reader.robot_get_obs(model, data, with_ball)
    reader.robot_get_obs(model, data, hinges)
    assert list(reader._robot_joints[1]) != list(reader._robot_joints[2])  # qpos ≠ qvel
    for read in ("get_site_xpos", "get_site_xmat", "get_site_xvelp", "get_site_xvelr"):
        assert _same(getattr(reader, read)(model, data, "tip"),
                     getattr(mujoco_utils, read)(model, data, "tip")), read
        with pytest.raises(AssertionError, match="Site with name 'nowhere'"):
            getattr(reader, read)(model, data, "nowhere")
    for name, value in (("robot0:slide", 0.25), ("box:joint", np.arange(7.0))):
        ours, theirs = _model_and_data(1), _model_and_data(1)
        reader.set_joint_qpos(*ours, name, value)
        mujoco_utils.set_joint_qpos(*theirs, name, value)
        assert ours[1].qpos.tobytes() == theirs[1].qpos.tobytes(), name
    # another model (same names, other state): the ids are resolved again, not reused
    other, other_data = _model_and_data(2)
    assert _same(reader.robot_get_obs(other, other_data, hinges),
                 mujoco_utils.robot_get_obs(other, other_data, hinges))
    assert reader._model is other


def test_other_envs_are_left_as_they_are() -> None:
    """PointMaze (gymnasium's MujocoEnv, no `_utils`) and plain objects take nothing."""
    maze = make_env(task_spec("PointMaze_UMaze-v3"))
    try:
        assert not hasattr(maze.unwrapped, "_utils")
    finally:
        maze.close()
    assert not index_lookups(object())


def test_v1_on_mujoco_py_is_left_as_it_is() -> None:
    skip_without_mujoco_py()
    env = make_env(task_spec("push", "v1"))
    try:
        assert env.unwrapped._utils.__name__ == "gymnasium_robotics.utils.mujoco_py_utils"
    finally:
        env.close()


def test_a_copy_of_the_reader_does_not_recurse() -> None:
    import copy

    from gymnasium_robotics.utils import mujoco_utils

    reader = IndexedMujocoUtils(mujoco_utils)
    assert copy.copy(reader).robot_get_obs is not None
    assert reader.get_joint_qpos is mujoco_utils.get_joint_qpos


def test_task_indexed_reads_false_makes_envs_read_by_name() -> None:
    from hercs.config import HercsConfig, apply_overrides

    config = apply_overrides(HercsConfig(), ["task.indexed_reads=false"])
    assert config.task.spec.indexed_reads is False
    env = make_env(config.task.spec)
    try:
        assert env.unwrapped._utils.__name__ == "gymnasium_robotics.utils.mujoco_utils"
    finally:
        env.close()
    assert HercsConfig().task.spec.indexed_reads is True
