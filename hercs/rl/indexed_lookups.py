"""The per-step reads of gymnasium-robotics' MuJoCo envs, from ids resolved once.

Every step of a Fetch v4 or Shadow hand env builds its observation through
`gymnasium_robotics.utils.mujoco_utils`, which looks each joint and site up by name and copies
the robot's joints a slice at a time: ~0.2 ms of a ~0.9 ms FetchPush step, pure Python
(docs/results/env_step.md). `IndexedMujocoUtils` stands in for that module on one env: the
functions a step calls answer from ids and joint addresses cached on first use, with the same
NumPy operations, so the values are bit-identical; every other name is the module's own.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

MUJOCO_UTILS = "gymnasium_robotics.utils.mujoco_utils"
"""The module a gymnasium-robotics env on the mujoco bindings reads through (`env._utils`)."""


class IndexedMujocoUtils:
    """`mujoco_utils` for one env's model: `robot_get_obs`, the site reads and the fingers'
    `set_joint_qpos` by cached ids."""

    def __init__(self, utils: ModuleType) -> None:
        import mujoco  # type: ignore[import-untyped]  # here: hercs.rl.envs may make no env

        self._mj = mujoco
        self._utils = utils
        self._model: Any = None
        self._forget()

    def _forget(self) -> None:
        """Drop the cached ids and addresses (they belong to one model)."""
        self._site_ids: dict[str, int] = {}
        self._robot_joints: tuple[tuple[str, ...], np.ndarray, np.ndarray] | None = None
        self._one_coordinate_qpos: dict[str, int | None] = {}

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name == "_utils":  # copy and pickle probe before __init__
            raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")
        return getattr(self._utils, name)

    def _same_model(self, model: Any) -> None:
        if model is not self._model:
            self._model = model
            self._forget()

    def _one_coordinate(self, model: Any, joint_id: int) -> bool:
        """Whether the joint exists and has one qpos coordinate (a slide or hinge joint)."""
        return joint_id != -1 and model.jnt_type[joint_id] in (
            self._mj.mjtJoint.mjJNT_HINGE, self._mj.mjtJoint.mjJNT_SLIDE)

    def _site_id(self, model: Any, name: str) -> int:
        self._same_model(model)
        site_id = self._site_ids.get(name)
        if site_id is None:
            site_id = self._mj.mj_name2id(model, self._mj.mjtObj.mjOBJ_SITE, name)
            assert site_id != -1, f"Site with name '{name}' is not part of the model!"
            self._site_ids[name] = site_id
        return site_id

    def _joint_addresses(self, model: Any,
                         joint_names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray] | None:
        """The qpos and qvel addresses of the robot's joints, or None where the module's own
        code must answer: a joint of more than one coordinate, or fewer than two joints (its
        squeeze then changes the shape)."""
        self._same_model(model)
        if self._robot_joints is None or self._robot_joints[0] is not joint_names:
            names = [n for n in joint_names if n.startswith("robot")]
            ids = [self._mj.mj_name2id(model, self._mj.mjtObj.mjOBJ_JOINT, n) for n in names]
            if len(ids) < 2 or not all(self._one_coordinate(model, i) for i in ids):
                qpos = qvel = np.empty(0, dtype=np.intp)
            else:
                qpos = np.array([model.jnt_qposadr[i] for i in ids], dtype=np.intp)
                qvel = np.array([model.jnt_dofadr[i] for i in ids], dtype=np.intp)
            self._robot_joints = (joint_names, qpos, qvel)
        _, qpos, qvel = self._robot_joints
        return (qpos, qvel) if qpos.size else None

    def robot_get_obs(self, model: Any, data: Any,
                      joint_names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        addresses = (self._joint_addresses(model, joint_names)
                     if data.qpos is not None and joint_names else None)
        if addresses is None:
            return self._utils.robot_get_obs(model, data, joint_names)
        qpos, qvel = addresses
        # fancy indexing copies, as the module's per-joint `.copy()` and `np.array` do
        return data.qpos[qpos], data.qvel[qvel]

    def set_joint_qpos(self, model: Any, data: Any, name: str, value: Any) -> None:
        """The gripper's fingers (slide joints) are set every step of Push, Reach and Slide: a
        slide or hinge joint's one coordinate is written by its cached address; other joints
        (the object's free joint, at a reset) by the module."""
        self._same_model(model)
        if name not in self._one_coordinate_qpos:
            joint_id = self._mj.mj_name2id(model, self._mj.mjtObj.mjOBJ_JOINT, name)
            self._one_coordinate_qpos[name] = (int(model.jnt_qposadr[joint_id])
                                               if self._one_coordinate(model, joint_id) else None)
        address = self._one_coordinate_qpos[name]
        if address is None:
            self._utils.set_joint_qpos(model, data, name, value)
            return
        data.qpos[address:address + 1] = np.array(value)

    def get_site_xpos(self, model: Any, data: Any, name: str) -> np.ndarray:
        return data.site_xpos[self._site_id(model, name)]

    def get_site_xmat(self, model: Any, data: Any, name: str) -> np.ndarray:
        return data.site_xmat[self._site_id(model, name)].reshape(3, 3)

    def get_site_xvelp(self, model: Any, data: Any, name: str) -> np.ndarray:
        jacp = self._utils.get_site_jacp(model, data, self._site_id(model, name))
        return jacp @ data.qvel

    def get_site_xvelr(self, model: Any, data: Any, name: str) -> np.ndarray:
        jacr = self._utils.get_site_jacr(model, data, self._site_id(model, name))
        return jacr @ data.qvel


def index_lookups(env: Any) -> bool:
    """Give `env` (a gymnasium-robotics MuJoCo env, wrapped or not) the indexed reads; returns
    whether it took them. Envs on mujoco-py (Fetch v1) and any other env are left as they are."""
    inner = getattr(env, "unwrapped", env)
    utils = getattr(inner, "_utils", None)
    if not isinstance(utils, ModuleType) or utils.__name__ != MUJOCO_UTILS:
        return False
    inner._utils = IndexedMujocoUtils(utils)
    return True
