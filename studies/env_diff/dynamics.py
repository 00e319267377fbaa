"""3 (a-c). Dynamics under the same actions: gripper tracking, a controlled push and a free
slide (the rollouts of 3 (d, e) and the variants' sweeps are studies/env_diff/rollouts.py)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from studies.env_diff.sim import G, Sim


def sim_key(s: Sim) -> str:
    return s.label


def start_all(sims: Sequence[Sim], seed: int,
              place: Callable[[Sim], None] | None = None) -> dict[str, np.ndarray]:
    """Reset every simulator with `seed`, optionally change the first one's state (`place`),
    then put the others in the first one's full simulator state and goal (matched states)."""
    first = sims[0]
    first.env.reset(seed=seed)
    if place is not None:
        place(first)
        first.forward()
    st, goal = first.state(), first.u.goal.copy()
    for s in sims[1:]:
        s.env.reset(seed=seed)
        s.set_state(st)
        s.u.goal = goal.copy()
    return first.obs()


def step_replica_check(sims: Sequence[Sim], steps: int) -> dict[str, float]:
    """Sim.step against env.step from the same saved state and the same random actions: the
    largest difference in any observation (0.0: the replica is exact)."""
    out: dict[str, float] = {}
    rng = np.random.default_rng(7)
    acts = rng.uniform(-1, 1, size=(steps, 4)).astype(np.float32)
    for s in sims:
        s.env.reset(seed=3)
        st = s.state()
        a = [s.env.step(x)[0]["observation"] for x in acts]
        s.set_state(st)
        b = [s.step(x)[0]["observation"] for x in acts]
        out[sim_key(s)] = float(np.abs(np.array(a) - np.array(b)).max())
    return out


def object_yaw(o: dict[str, np.ndarray]) -> float:
    return float(o["observation"][13])


def object_tilt(o: dict[str, np.ndarray]) -> float:
    return float(np.abs(o["observation"][11:13]).max())


def wrap_angle(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def gripper_tracking(sims: Sequence[Sim]) -> dict[str, Any]:
    """Free space (after a 10 cm lift): per axis and action size, 6 steps one way, 3 of zero,
    6 steps back, 3 of zero; the mean displacement per step over the last 4 of each 6."""
    seq: list[tuple[str, np.ndarray]] = [("lift", np.array([0, 0, 1, 0.0]))] * 3
    for mag in (1.0, 0.5, 0.2):
        for ax in range(3):
            for sign in (1.0, -1.0) if ax != 2 else (-1.0, 1.0):
                a = np.zeros(4)
                a[ax] = sign * mag * (0.5 if ax == 2 else 1.0)  # z: stay above the table
                seq += [(f"{'xyz'[ax]} {a[ax]:+.2g}", a)] * 6 + [("stop", np.zeros(4))] * 3
    traj: dict[str, np.ndarray] = {}
    start_all(sims, 0)
    for s in sims:
        o = s.obs()
        g = [o["observation"][:3].copy()]
        for _, a in seq:
            g.append(s.step(a)[0]["observation"][:3].copy())
        traj[sim_key(s)] = np.diff(np.array(g), axis=0)
    out: dict[str, Any] = {}
    labels = sorted({lab for lab, _ in seq if lab not in ("stop", "lift")},
                    key=lambda x: (x[0], -abs(float(x[2:])), -float(x[2:])))
    for k, d in traj.items():
        speeds: dict[str, float] = {}
        for label in labels:
            idx = [i for i, (lab, _) in enumerate(seq) if lab == label]
            ax = "xyz".index(label[0])
            speeds[label] = round(1e3 * float(np.mean([d[i, ax] for i in idx[2:6]])), 3)
        first_stop = [i for i, (lab, _) in enumerate(seq)
                      if lab == "stop" and seq[i - 1][0] != "stop"]
        out[k] = {"steady_mm_per_step": speeds,
                  "coast_after_stop_mm": round(1e3 * float(np.mean(
                      [np.linalg.norm(d[i]) for i in first_stop])), 3)}
    out["max_per_step_diff_mm"] = {k: round(1e3 * float(np.abs(traj[k] - traj["v1"]).max()), 4)
                                   for k in traj if k != "v1"}
    return out


def push_probe(sims: Sequence[Sim], seeds: Sequence[int], mags: Sequence[float],
               ) -> dict[str, Any]:
    """The object placed 6 cm in front of the fingers along ±y, pushed at `mag` of full speed
    for about 12 cm, then the gripper withdrawn at the same speed for 3 steps and held for 6;
    from the same (v1's) state in every simulator."""
    per: dict[str, list[dict[str, float]]] = {sim_key(s): [] for s in sims}
    for seed in seeds:
        for mag in mags:
            for sign in (1.0, -1.0):
                def place(s: Sim, sign: float = sign) -> None:
                    qa, da = s.object_qpos_adr(), s.object_dof_adr()
                    grip = np.array(s.data.site_xpos[s.id("site", "robot0:grip")])
                    s.data.qpos[qa:qa + 2] = grip[:2] + np.array([0.0, 0.06 * sign])
                    s.data.qpos[qa + 2] = s.u.height_offset
                    s.data.qpos[qa + 3:qa + 7] = [1, 0, 0, 0]
                    s.data.qvel[da:da + 6] = 0

                o = start_all(sims, seed, place)
                k = round(0.12 / (0.033 * mag)) + 1
                acts = [np.array([0, sign * mag, 0, 0])] * k \
                    + [np.array([0, -sign * mag, 0, 0])] * 3 + [np.zeros(4)] * 6
                # where the gripper starts above the object (pick), first down beside it
                drop = float(o["observation"][2] - o["achieved_goal"][2])
                down = [np.array([0, 0, -1.0, 0])] * int(drop / 0.033) if drop > 0.02 else []
                for s in sims:
                    for a in down:
                        s.step(a)
                    per[sim_key(s)].append(_push_metrics(s, acts, k, sign, mag))
    out: dict[str, Any] = {}
    for key, rows in per.items():
        out[key] = {}
        for mag in mags:
            sel = [r for r in rows if r["mag"] == mag]
            out[key][f"{mag:g}"] = {m: round(float(np.mean([r[m] for r in sel])), 4)
                                    for m in sel[0] if m != "mag"}
    return out


def _push_metrics(s: Sim, acts: list[np.ndarray], k: int, sign: float,
                  mag: float) -> dict[str, float]:
    o = s.obs()
    obj0, yaw0 = o["achieved_goal"].copy(), object_yaw(o)
    objs, grips, touch = [obj0], [o["observation"][:3].copy()], []
    tilt = 0.0
    for a in acts:
        o, _, _, n = s.step(a)
        objs.append(o["achieved_goal"].copy())
        grips.append(o["observation"][:3].copy())
        touch.append(n)
        tilt = max(tilt, object_tilt(o))
    objs_a, grips_a = np.array(objs), np.array(grips)
    dobj = np.diff(objs_a[:, 1]) * sign
    dgrip = np.diff(grips_a[:, 1]) * sign
    during = [i for i in range(k) if touch[i]]
    moved = float(dobj[during].sum()) if during else 0.0
    pushed = float(dgrip[during].sum()) if during else 0.0
    last = max((i for i, t in enumerate(touch) if t), default=-1)
    after = objs_a[last + 1:]
    slide = float(np.linalg.norm(after[-1, :2] - after[0, :2])) if last >= 0 else 0.0
    moving = int(np.sum(np.linalg.norm(np.diff(after[:, :2], axis=0), axis=1) > 5e-4))
    return {"mag": mag,
            "object_travel_cm": 100 * float(dobj.sum()),
            "gripper_travel_touching_cm": 100 * pushed,
            "object_per_gripper_travel": moved / pushed if pushed > 1e-6 else 0.0,
            "touching_substeps": float(sum(touch)),
            "slide_after_contact_mm": 1e3 * slide,
            "steps_moving_after_contact": float(moving),
            "object_lateral_drift_mm": 1e3 * abs(float(objs_a[-1, 0] - obj0[0])),
            "object_yaw_change_deg": math.degrees(abs(wrap_angle(object_yaw(o) - yaw0))),
            "object_max_tilt_deg": math.degrees(tilt)}


def slide_probe(sims: Sequence[Sim], distances: Sequence[float]) -> dict[str, Any]:
    """The object launched along +y on the table (gripper held still 12 cm away), stepped
    substep by substep for 0.6 s: stopping distance and time against Coulomb's v0²/(2 μ g), μ
    the larger of the object's and the table's sliding friction (MuJoCo's pair rule)."""
    s1 = sims[0]
    m = s1.model
    mu = float(max(m.geom_friction[s1.object_geom][0], m.geom_friction[min(s1.table_geoms)][0]))
    out: dict[str, Any] = {"mu": mu, "rows": []}
    for d in distances:
        v0 = math.sqrt(2 * mu * G * d)

        def place(s: Sim, v0: float = v0) -> None:
            s.mocap_to_gripper()
            qa, da = s.object_qpos_adr(), s.object_dof_adr()
            grip = np.array(s.data.site_xpos[s.id("site", "robot0:grip")])
            s.data.qpos[qa:qa + 2] = grip[:2] + np.array([-0.12, -0.02])
            s.data.qpos[qa + 2] = s.u.height_offset
            s.data.qpos[qa + 3:qa + 7] = [1, 0, 0, 0]
            s.data.qvel[da:da + 6] = [0, v0, 0, 0, 0, 0]

        start_all(sims, 0, place)
        row: dict[str, Any] = {"v0_m_s": round(v0, 4), "coulomb_cm": round(100 * d, 3),
                               "coulomb_stop_s": round(v0 / (mu * G), 4)}
        for s in sims:
            site = s.id("site", "object0")
            p0 = np.array(s.data.site_xpos[site])
            dt = float(s.model.opt.timestep)
            stop = slow = None
            for i in range(int(0.6 / dt)):
                s.substep()
                v = float(np.linalg.norm(s.object_velocity()[:3]))
                if slow is None and v < 0.05 * v0:
                    slow = round((i + 1) * dt, 4)
                if stop is None and v < 1e-3:
                    stop = round((i + 1) * dt, 4)
            p1 = np.array(s.data.site_xpos[site])
            travel = float(np.linalg.norm(p1[:2] - p0[:2]))
            row[sim_key(s)] = {"distance_cm": round(100 * travel, 4),
                            "below_5pct_v0_s": slow, "below_1mm_s_s": stop,
                            "z_change_mm": round(1e3 * float(p1[2] - p0[2]), 4),
                            "lateral_mm": round(1e3 * float(abs(p1[0] - p0[0])), 4)}
        out["rows"].append(row)
    return out
