"""1. Models: the physics options and the contact and motion parameters of v1 and v4 side by
side, then every numeric mjModel field the two bindings share."""

from __future__ import annotations

from typing import Any

import numpy as np

from studies.env_diff.sim import (
    ATOL,
    CONES,
    GEOM_TYPES,
    INTEGRATORS,
    JACOBIANS,
    MESH,
    RTOL,
    SOLVERS,
    Sim,
    json_value,
)


def _equal(a: Any, b: Any) -> bool:
    if a is None or b is None:
        return False
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=RTOL, atol=ATOL))


def _flags(bits: int, names: dict[int, str]) -> str:
    on = [n for v, n in names.items() if bits & v]
    return ", ".join(on) or "none"


def _v1_flag_names(prefix: str) -> dict[int, str]:
    import mujoco_py

    return {int(getattr(mujoco_py.const, n)): n.removeprefix(prefix).lower()
            for n in dir(mujoco_py.const) if n.startswith(prefix)}


def _v4_flag_names(enum: Any, prefix: str) -> dict[int, str]:
    return {int(v): n.removeprefix(prefix).lower() for n, v in enum.__members__.items()
            if not n.startswith(("mjNDISABLE", "mjNENABLE"))}


def option_rows(s1: Sim, s4: Sim) -> list[dict[str, Any]]:
    import mujoco

    o1, o4 = s1.model.opt, s4.model.opt
    rows: list[dict[str, Any]] = []

    def row(param: str, a: Any, b: Any, note: str = "") -> None:
        rows.append({"group": "options", "param": param, "v1": json_value(a), "v4": json_value(b),
                     "equal": _equal(a, b), "note": note})

    row("timestep (s)", o1.timestep, o4.timestep)
    row("n_substeps", s1.u.sim.nsubsteps, s4.u.n_substeps)
    row("env dt (s)", s1.u.dt, s4.u.dt, "control period: timestep x substeps")
    row("integrator", INTEGRATORS[int(o1.integrator)], INTEGRATORS[int(o4.integrator)])
    row("solver", SOLVERS[int(o1.solver)], SOLVERS[int(o4.solver)])
    row("iterations", o1.iterations, o4.iterations)
    row("tolerance", o1.tolerance, o4.tolerance)
    row("cone", CONES[int(o1.cone)], CONES[int(o4.cone)])
    row("impratio", o1.impratio, o4.impratio)
    row("noslip_iterations", o1.noslip_iterations, o4.noslip_iterations)
    row("noslip_tolerance", o1.noslip_tolerance, o4.noslip_tolerance)
    row("gravity", o1.gravity, o4.gravity)
    for k in ("wind", "magnetic", "density", "viscosity", "o_margin", "o_solref", "o_solimp"):
        row(k, getattr(o1, k), getattr(o4, k))
    row("jacobian", JACOBIANS[int(o1.jacobian)], JACOBIANS[int(o4.jacobian)])
    d1 = _v1_flag_names("DSBL_")
    d4 = _v4_flag_names(mujoco.mjtDisableBit, "mjDSBL_")
    e1 = _v1_flag_names("ENBL_")
    e4 = _v4_flag_names(mujoco.mjtEnableBit, "mjENBL_")
    row("disableflags set", _flags(int(o1.disableflags), d1), _flags(int(o4.disableflags), d4))
    row("enableflags set", _flags(int(o1.enableflags), e1), _flags(int(o4.enableflags), e4))
    new = sorted(set(d4.values()) - set(d1.values()))
    row("disable flags only MuJoCo 3 has (clear = feature on)",
        None, ", ".join(f"{n}: {'off' if int(o4.disableflags) & k else 'on'}"
                        for k, n in d4.items() if n in new),
        "MuJoCo 2.1's flags: " + ", ".join(sorted(d1.values())))
    row("enable flags only MuJoCo 3 has", None,
        ", ".join(f"{n}: {'on' if int(o4.enableflags) & k else 'off'}"
                  for k, n in e4.items() if n not in set(e1.values())))
    for k in ("ls_iterations", "ls_tolerance", "ccd_iterations", "ccd_tolerance", "o_friction",
              "sleep_tolerance", "sdf_iterations"):
        if hasattr(o4, k):
            row(k, None, getattr(o4, k), "MuJoCo 3 only")
    for k in ("mpr_iterations", "mpr_tolerance", "collision"):
        row(k, getattr(o1, k), None, "MuJoCo 2.1 only")
    row("nconmax / njmax", [s1.model.nconmax, s1.model.njmax],
        [s4.model.nconmax, s4.model.njmax], "-1: sized at run time")
    return rows


GEOM_FIELDS = ("geom_type", "geom_size", "geom_friction", "geom_condim", "geom_solref",
               "geom_solimp", "geom_solmix", "geom_margin", "geom_gap", "geom_priority",
               "geom_contype", "geom_conaffinity")


def model_rows(s1: Sim, s4: Sim) -> list[dict[str, Any]]:
    """The parameters that decide contact and motion of the object, table, floor, gripper."""
    m1, m4 = s1.model, s4.model
    rows: list[dict[str, Any]] = []

    def row(group: str, param: str, a: Any, b: Any, note: str = "") -> None:
        rows.append({"group": group, "param": param, "v1": json_value(a), "v4": json_value(b),
                     "equal": _equal(a, b), "note": note})

    def body(group: str, name: str) -> None:
        b1, b4 = s1.id("body", name), s4.id("body", name)
        for f in ("body_mass", "body_inertia", "body_ipos"):
            row(group, f"{name} {f.removeprefix('body_')}", getattr(m1, f)[b1],
                getattr(m4, f)[b4])

    def geom(group: str, label: str, g1: int, g4: int) -> None:
        for f in GEOM_FIELDS:
            a, b = getattr(m1, f)[g1], getattr(m4, f)[g4]
            if f == "geom_type":
                a, b = GEOM_TYPES[int(a)], GEOM_TYPES[int(b)]
            if f == "geom_size" and int(m1.geom_type[g1]) == MESH:
                continue  # a mesh's size is its frame's bounding box, compared in `all fields`
            row(group, f"{label} {f.removeprefix('geom_')}", a, b)

    def joint(group: str, name: str) -> None:
        j1, j4 = s1.id("joint", name), s4.id("joint", name)
        d1, d4 = int(m1.jnt_dofadr[j1]), int(m4.jnt_dofadr[j4])
        n = 6 if int(m1.jnt_type[j1]) == 0 else 1
        for f in ("dof_damping", "dof_armature", "dof_frictionloss"):
            row(group, f"{name} {f.removeprefix('dof_')}", getattr(m1, f)[d1:d1 + n],
                getattr(m4, f)[d4:d4 + n])
        for f in ("jnt_stiffness", "jnt_range", "jnt_limited", "jnt_solref", "jnt_solimp"):
            row(group, f"{name} {f.removeprefix('jnt_')}", getattr(m1, f)[j1],
                getattr(m4, f)[j4])

    body("object", "object0")
    geom("object", "object0 geom", s1.object_geom, s4.object_geom)
    joint("object", "object0:joint")
    body("table", "table0")
    geom("table", "table0 geom", min(s1.table_geoms), min(s4.table_geoms))
    geom("floor", "floor0 geom", s1.id("geom", "floor0"), s4.id("geom", "floor0"))
    for side in "lr":
        name = f"robot0:{side}_gripper_finger_link"
        body("fingers", name)
        geom("fingers", f"{name} geom", s1.id("geom", name), s4.id("geom", name))
        joint("fingers", f"robot0:{side}_gripper_finger_joint")
    geom("gripper", "robot0:gripper_link geom", s1.id("geom", "robot0:gripper_link"),
         s4.id("geom", "robot0:gripper_link"))
    body("gripper", "robot0:gripper_link")
    row("actuators", "nu (actuators)", m1.nu, m4.nu,
        "" if m1.nu else "none: the fingers are held shut by _step_callback (block_gripper)")
    for a in range(int(m1.nu)):
        name = s1.name("actuator", a)
        a4 = s4.id("actuator", name)
        for f, sl in (("actuator_gainprm", slice(0, 3)), ("actuator_biasprm", slice(0, 3)),
                      ("actuator_ctrlrange", slice(None)), ("actuator_ctrllimited", None),
                      ("actuator_forcerange", slice(None)), ("actuator_forcelimited", None),
                      ("actuator_gear", slice(0, 1)), ("actuator_biastype", None),
                      ("actuator_dyntype", None)):
            a1v, a4v = getattr(m1, f)[a], getattr(m4, f)[a4]
            if sl is not None:
                a1v, a4v = a1v[sl], a4v[sl]
            row("actuators", f"{name} {f.removeprefix('actuator_')}", a1v, a4v)
    # the mocap weld: MuJoCo 2.1 stores relpose in eq_data[0:7]; MuJoCo 3 anchor[0:3],
    # relpose[3:10], torquescale[10] (both after gymnasium-robotics' reset_mocap_welds)
    for e in range(int(m1.neq)):
        row("mocap weld", "eq_solref", m1.eq_solref[e], m4.eq_solref[e])
        row("mocap weld", "eq_solimp", m1.eq_solimp[e], m4.eq_solimp[e])
        row("mocap weld", "relpose (pos, quat)", m1.eq_data[e][0:7], m4.eq_data[e][3:10])
        row("mocap weld", "anchor", None, m4.eq_data[e][0:3], "MuJoCo 3 only")
        row("mocap weld", "torquescale", None, m4.eq_data[e][10], "MuJoCo 3 only")
        row("mocap weld", "active", int(m1.eq_active[e]), int(m4.eq_active0[e]))
    return rows


BOOKKEEPING = {
    "body_sameframe": "frame-coincidence flags MuJoCo 3 computes for speed",
    "geom_sameframe": "frame-coincidence flags MuJoCo 3 computes for speed",
    "site_sameframe": "frame-coincidence flags MuJoCo 3 computes for speed",
    "exclude_signature": "body-pair hash of the <exclude> pairs (encoding differs)",
    "nbuffer": "model buffer size",
    "nconmax": "contact buffer size (MuJoCo 3 sizes it at run time)",
    "njmax": "constraint buffer size (MuJoCo 3 sizes it at run time)",
    "nuser_geom": "user data width (the XML's user=\"0\"); unused by the physics",
    "nmeshvert": "mesh vertices: MuJoCo 3 merges duplicate STL vertices",
    "mesh_vertadr": "mesh vertex addresses (follow the vertex counts)",
    "mesh_vertnum": "mesh vertex counts (duplicates merged in MuJoCo 3)",
    "mesh_face": "mesh faces index the (renumbered) vertices",
    "mesh_graph": "convex-hull graph indexes the (renumbered) vertices",
}


def all_field_rows(s1: Sim, s4: Sim) -> dict[str, Any]:
    """Every numeric mjModel field both bindings have, element by element."""
    m1, m4 = s1.model, s4.model
    f1 = {a for a in dir(m1) if not a.startswith("_")}
    f4 = {a for a in dir(m4) if not a.startswith("_")}
    differ, shapes, equal = [], [], 0
    for k in sorted(f1 & f4):
        try:
            a, b = getattr(m1, k), getattr(m4, k)
        except Exception:  # a property one binding cannot read for this model
            continue
        if callable(a) or callable(b):
            continue
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype.kind not in "fiub" or b.dtype.kind not in "fiub":
            continue
        if a.shape != b.shape:
            shapes.append({"field": k, "v1": list(a.shape), "v4": list(b.shape),
                           "note": BOOKKEEPING.get(k, _shape_note(k))})
            continue
        af, bf = a.astype(float), b.astype(float)
        close = np.isclose(af, bf, rtol=RTOL, atol=ATOL)
        if close.all():
            equal += 1
            continue
        bad = np.argwhere(~close)
        rows_bad = sorted({int(i[0]) for i in bad}) if a.ndim else []
        note = BOOKKEEPING.get(k, "")
        if k.startswith("geom_") and rows_bad:
            types = {GEOM_TYPES[int(m1.geom_type[g])] for g in rows_bad}
            names = [s1.name("geom", g) or f"#{g}" for g in rows_bad]
            note = note or (f"only mesh geoms ({', '.join(names)}): a mesh geom's frame is its "
                            "mesh's inertia frame (shape unchanged, checked below)"
                            if types == {"mesh"} else f"geoms {names}")
        differ.append({"field": k, "shape": list(a.shape), "elements": len(bad),
                       "max_abs_diff": float(np.abs(af - bf)[~close].max()),
                       "first": {"index": bad[0].tolist(), "v1": json_value(af[tuple(bad[0])]),
                                 "v4": json_value(bf[tuple(bad[0])])},
                       "note": note})
    return {"equal_fields": equal, "differ": differ, "shape_differs": shapes,
            "only_v1": len(f1 - f4), "only_v4": len(f4 - f1), "meshes": mesh_check(s1, s4)}


def _shape_note(k: str) -> str:
    return {"eq_data": "weld data layout: 2.1 relpose[7]; 3 anchor, relpose, torquescale[11]",
            "mat_texid": "MuJoCo 3 materials have one texture slot per role",
            "mesh_vert": "mesh vertices (duplicates merged in MuJoCo 3)",
            "mesh_normal": "mesh normals (follow the vertices)"}.get(k, "")


def mesh_check(s1: Sim, s4: Sim) -> dict[str, Any]:
    """Whether each mesh geom has the same shape in the body frame: vertices placed by the
    geom's pos/quat, compared by their bounding box and the number of distinct vertices."""
    m1, m4 = s1.model, s4.model
    worst_box, same_count = 0.0, True
    for g in range(int(m1.ngeom)):
        if int(m1.geom_type[g]) != MESH:
            continue
        boxes, counts = [], []
        for m in (m1, m4):
            mid = int(m.geom_dataid[g])
            adr, n = int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid])
            v = np.asarray(m.mesh_vert[adr:adr + n], dtype=float)
            q = np.asarray(m.geom_quat[g], dtype=float)
            body = v @ _quat_mat(q).T + np.asarray(m.geom_pos[g], dtype=float)
            boxes.append(np.concatenate([body.min(0), body.max(0)]))
            counts.append(len(np.unique(np.round(v, 5), axis=0)))
        worst_box = max(worst_box, float(np.abs(boxes[0] - boxes[1]).max()))
        same_count &= abs(counts[0] - counts[1]) <= max(2, counts[1] // 200)
    return {"body_frame_bbox_max_diff_m": worst_box, "distinct_vertices_match": bool(same_count)}


def _quat_mat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
