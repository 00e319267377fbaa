"""One interface over mujoco-py (v1) and the mujoco bindings (v4): `Sim`, the v1/v4 pair of a
task, and the v4 model variants (`--variant`)."""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from hercs.rl.envs import make_env, mujoco_py_problem
from hercs.rl.task_registry import task_spec

TASKS = ("push", "pick", "slide")
G = 9.81
RTOL, ATOL = 1e-6, 1e-9
"""Two parameters are equal when np.allclose(v1, v4, RTOL, ATOL) (float32 round-trips stay
equal)."""

INTEGRATORS = {0: "Euler", 1: "RK4", 2: "implicit", 3: "implicitfast"}
CONES = {0: "pyramidal", 1: "elliptic"}
SOLVERS = {0: "PGS", 1: "CG", 2: "Newton"}
JACOBIANS = {0: "dense", 1: "sparse", 2: "auto"}
GEOM_TYPES = {0: "plane", 1: "hfield", 2: "sphere", 3: "capsule", 4: "ellipsoid",
              5: "cylinder", 6: "box", 7: "mesh"}
MESH = 7


# --------------------------------------------------------------------------------------------
# one interface over mujoco-py (v1) and the mujoco bindings (v4)
# --------------------------------------------------------------------------------------------


class Sim:
    """One Fetch env's simulator: names, state, contacts, single substeps."""

    def __init__(self, env: Any, version: str) -> None:
        self.env = env
        self.u = env.unwrapped
        self.version = version
        self.label = version
        if version == "v1":
            from mujoco_py import functions

            self._fn = functions
            self.model = self.u.sim.model
            self.data = self.u.sim.data
        else:
            import mujoco

            self._mj = mujoco
            self.model = self.u.model
            self.data = self.u.data
        m = self.model
        self.object_geom = self.id("geom", "object0")
        self.robot_geoms = {g for g in range(m.ngeom) if (
            self.name("body", int(m.geom_bodyid[g])) or "").startswith("robot0:")}
        table = self.id("body", "table0")
        self.table_geoms = {g for g in range(m.ngeom) if int(m.geom_bodyid[g]) == table}
        self.finger_geoms = [self.id("geom", f"robot0:{s}_gripper_finger_link") for s in "lr"]
        self.substeps = int(self.u.sim.nsubsteps if version == "v1" else self.u.n_substeps)

    def id(self, kind: str, name: str) -> int:
        if self.version == "v1":
            try:
                return int(getattr(self.model, f"{kind}_name2id")(name))
            except ValueError:
                return -1
        obj = getattr(self._mj.mjtObj, f"mjOBJ_{'JOINT' if kind == 'joint' else kind.upper()}")
        return int(self._mj.mj_name2id(self.model, obj, name))

    def name(self, kind: str, i: int) -> str | None:
        if self.version == "v1":
            return getattr(self.model, f"{kind}_id2name")(i)
        obj = getattr(self._mj.mjtObj, f"mjOBJ_{'JOINT' if kind == 'joint' else kind.upper()}")
        return self._mj.mj_id2name(self.model, obj, i)

    def forward(self) -> None:
        if self.version == "v1":
            self.u.sim.forward()
        else:
            self._mj.mj_forward(self.model, self.data)

    def substep(self) -> None:
        if self.version == "v1":
            self._fn.mj_step(self.model, self.data)
        else:
            self._mj.mj_step(self.model, self.data)

    STATE = ("qpos", "qvel", "mocap_pos", "mocap_quat", "qacc_warmstart")

    def state(self) -> dict[str, np.ndarray]:
        return {k: np.array(getattr(self.data, k)) for k in self.STATE}

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        for k in self.STATE:
            getattr(self.data, k)[:] = st[k]
        self.forward()

    def contacts(self) -> list[tuple[int, int]]:
        n = int(self.data.ncon)
        if self.version == "v1":
            return [(int(self.data.contact[i].geom1), int(self.data.contact[i].geom2))
                    for i in range(n)]
        return list(zip(self.data.contact.geom1[:n].tolist(),
                        self.data.contact.geom2[:n].tolist(), strict=True))

    def contact_counts(self) -> dict[str, int]:
        """Contacts now, by pair kind."""
        counts = {"object-robot": 0, "object-table": 0, "robot-table": 0, "object-floor": 0}
        for a, b in self.contacts():
            pair = {a, b}
            if self.object_geom in pair:
                other = (pair - {self.object_geom}) or {self.object_geom}
                o = next(iter(other))
                if o in self.robot_geoms:
                    counts["object-robot"] += 1
                elif o in self.table_geoms:
                    counts["object-table"] += 1
                elif self.name("geom", o) == "floor0":
                    counts["object-floor"] += 1
            elif pair & self.robot_geoms and pair & self.table_geoms:
                counts["robot-table"] += 1
        return counts

    def obs(self) -> dict[str, np.ndarray]:
        return self.u._get_obs()

    def gripper_tilt(self) -> float:
        """Degrees between the gripper link's orientation and the one every action asks for
        (the quaternion (1, 0, 1, 0)/√2 of gymnasium-robotics' _set_action)."""
        b = self.id("body", "robot0:gripper_link")
        q = np.array((self.data.body_xquat if self.version == "v1" else self.data.xquat)[b])
        target = np.array([1.0, 0.0, 1.0, 0.0]) / math.sqrt(2.0)
        return math.degrees(2 * math.acos(min(1.0, abs(float(q @ target)))))

    def touching(self) -> bool:
        """Whether the object touches the robot now."""
        return any((a == self.object_geom and b in self.robot_geoms)
                   or (b == self.object_geom and a in self.robot_geoms)
                   for a, b in self.contacts())

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, int]:
        """gymnasium-robotics' BaseRobotEnv.step, substep by substep (its _mujoco_step is
        n_substeps mj_steps on both bindings): the observation, the env's reward and success,
        and in how many substeps the object touched the robot. `step_replica_check` tests that
        it gives env.step's numbers exactly."""
        a = np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)
        self.u._set_action(a)
        touch = 0
        for _ in range(self.substeps):
            self.substep()
            touch += self.touching()
        self.u._step_callback()
        o = self.u._get_obs()
        success = bool(self.u._is_success(o["achieved_goal"], self.u.goal))
        r = float(self.u.compute_reward(o["achieved_goal"], self.u.goal, {}))
        return o, r, success, touch

    def mocap_to_gripper(self) -> None:
        """Put the mocap on the gripper (what every env step does first), so that raw substeps
        hold the gripper where it is."""
        self.u._utils.reset_mocap2body_xpos(*((self.u.sim,) if self.version == "v1"
                                               else (self.model, self.data)))
        self.forward()

    def object_qpos_adr(self) -> int:
        return int(self.model.jnt_qposadr[self.id("joint", "object0:joint")])

    def object_dof_adr(self) -> int:
        return int(self.model.jnt_dofadr[self.id("joint", "object0:joint")])

    def object_velocity(self) -> np.ndarray:
        a = self.object_dof_adr()
        return np.array(self.data.qvel[a:a + 6])

    def geom_bottom(self, g: int) -> float:
        """Lowest world z of a box geom."""
        r = np.array(self.data.geom_xmat[g]).reshape(3, 3)
        half = float(np.abs(r[2]) @ np.array(self.model.geom_size[g]))
        return float(self.data.geom_xpos[g][2]) - half

    def table_top(self) -> float:
        g = min(self.table_geoms)
        return float(self.data.geom_xpos[g][2]) + float(self.model.geom_size[g][2])


def make_pair(task: str) -> tuple[Sim, Sim]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        e1 = make_env(task_spec(task, "v1"))
        e4 = make_env(task_spec(task, "v4"))
    e1.reset(seed=0)
    e4.reset(seed=0)
    return Sim(e1, "v1"), Sim(e4, "v4")


def apply_variant(sim: Sim, name: str) -> str:
    """Change a v4 simulator's model as `name` says; returns what it did. Names: legacy-ccd,
    no-island, ls-tight, torquescale=X (the mocap weld's rotational weight, 1 by default), or
    several joined by '+'."""
    import mujoco

    if "+" in name:
        return "; ".join(apply_variant(sim, part) for part in name.split("+"))
    dsbl = mujoco.mjtDisableBit
    opt = sim.model.opt
    if name == "legacy-ccd":
        opt.disableflags |= int(dsbl.mjDSBL_NATIVECCD) | int(dsbl.mjDSBL_MULTICCD)
        return "native and multi-point CCD disabled (libccd's MPR, as in MuJoCo 2.1)"
    if name == "no-island":
        opt.disableflags |= int(dsbl.mjDSBL_ISLAND)
        return "constraint islands disabled (one constraint system, as in MuJoCo 2.1)"
    if name == "ls-tight":
        opt.ls_tolerance, opt.ls_iterations = 1e-6, 100
        return "Newton line search to tolerance 1e-6 in up to 100 iterations (default 0.01, 50)"
    if name.startswith("torquescale="):
        value = float(name.split("=", 1)[1])
        sim.model.eq_data[:, 10] = value
        return (f"mocap weld torquescale {value:g} (default 1): the weld's rotational rows "
                "weighted as in MuJoCo 2.x (hypothesis from mujoco issue #1483)")
    raise ValueError(f"unknown variant {name!r}")


def variant_name(name: str) -> str:
    for part in name.split("+"):
        if part in ("legacy-ccd", "no-island", "ls-tight"):
            continue
        if part.startswith("torquescale="):
            try:
                if float(part.split("=", 1)[1]) > 0:
                    continue
            except ValueError:
                pass
        raise argparse.ArgumentTypeError(
            f"unknown variant {name!r}: legacy-ccd, no-island, ls-tight or torquescale=X "
            "(X > 0), or several joined by +")
    return name


def xml_variant_setup(task: str, value: float, legacy_ccd: bool) -> dict[str, Any]:
    """The initial state of v4 built from a copy of its XML with the weld's torquescale at
    `value` and, with `legacy_ccd`, native and multi-point CCD off (so that the setup's 200
    substeps run with them too, unlike `apply_variant`, which changes the model after the
    setup): the initial gripper, the object's resting height, its contacts with the table."""
    import importlib
    import tempfile

    mujoco_py_problem()  # points mujoco-py at MuJoCo 2.1 before gymnasium-robotics imports it
    import gymnasium_robotics.envs.robot_env as robot_env

    module = importlib.import_module(
        {"push": "gymnasium_robotics.envs.fetch.push",
         "pick": "gymnasium_robotics.envs.fetch.pick_and_place",
         "slide": "gymnasium_robotics.envs.fetch.slide"}[task])
    assets = Path(robot_env.__file__).parent / "assets"
    xml = Path(module.MODEL_XML_PATH)
    with tempfile.TemporaryDirectory() as tmp:
        for name in (xml.name, "shared.xml", "robot.xml"):
            text = (assets / xml.parent / name).read_text()
            text = text.replace('meshdir="../stls/fetch"',
                                f'meshdir="{(assets / "stls" / "fetch").resolve()}"')
            text = text.replace('texturedir="../textures"',
                                f'texturedir="{(assets / "textures").resolve()}"')
            if name == xml.name and legacy_ccd:
                text = text.replace('<flag warmstart="enable">',
                                    '<flag warmstart="enable" nativeccd="disable" '
                                    'multiccd="disable">')
                assert "nativeccd" in text, f"the <flag> in {name} changed"
            if name == "shared.xml":
                weld = '<weld body1="robot0:mocap"'
                assert weld in text, "the weld in shared.xml changed"
                text = text.replace(weld, f'{weld} torquescale="{value:g}"')
            (Path(tmp) / name).write_text(text)
        old = module.MODEL_XML_PATH
        module.MODEL_XML_PATH = str(Path(tmp) / xml.name)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                env = make_env(task_spec(task, "v4"))
        finally:
            module.MODEL_XML_PATH = old
    env.reset(seed=0)
    sim = Sim(env, "v4")
    u = env.unwrapped
    out = {"torquescale": float(u.model.eq_data[0, 10]), "legacy_ccd": legacy_ccd,
           "disableflags": int(u.model.opt.disableflags),
           "initial_gripper_xpos": json_value(u.initial_gripper_xpos),
           "height_offset": json_value(u.height_offset),
           "object_table_contacts": sim.contact_counts()["object-table"]}
    env.close()
    return out


def make_v4_variant(task: str, name: str) -> tuple[Sim, str]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        e = make_env(task_spec(task, "v4"))
    e.reset(seed=0)
    sim = Sim(e, "v4")
    desc = apply_variant(sim, name)
    sim.label = f"v4:{name}"
    return sim, desc


def json_value(x: Any) -> Any:
    """A JSON-able value: floats rounded to 9 significant digits, arrays as lists."""
    if x is None or isinstance(x, str):
        return x
    a = np.asarray(x)
    if a.dtype.kind in "iub":
        return a.tolist()
    a = a.astype(float)
    if a.ndim == 0:
        return float(f"{float(a):.9g}")
    return [json_value(v) for v in a]
