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
        # the robot's joints were read by address, not handed back to the module
        joints = indexed.unwrapped._utils._robot_joints
        assert joints is not None and joints[1].size >= 2, joints
    finally:
        by_name.close()
        indexed.close()


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
