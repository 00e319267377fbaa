"""3. Dynamics under the same actions: gripper tracking, a controlled push, a free slide, and
scripted and random rollouts from matched and own initial states."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from hercs.rl.task_registry import fetch_reward
from studies.env_diff.sim import G, Sim, make_v4_variant


def _key(s: Sim) -> str:
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
        out[_key(s)] = float(np.abs(np.array(a) - np.array(b)).max())
    return out


def _yaw(o: dict[str, np.ndarray]) -> float:
    return float(o["observation"][13])


def _tilt(o: dict[str, np.ndarray]) -> float:
    return float(np.abs(o["observation"][11:13]).max())


def _wrap(a: float) -> float:
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
        traj[_key(s)] = np.diff(np.array(g), axis=0)
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
    per: dict[str, list[dict[str, float]]] = {_key(s): [] for s in sims}
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
                    per[_key(s)].append(_push_metrics(s, acts, k, sign, mag))
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
    obj0, yaw0 = o["achieved_goal"].copy(), _yaw(o)
    objs, grips, touch = [obj0], [o["observation"][:3].copy()], []
    tilt = 0.0
    for a in acts:
        o, _, _, n = s.step(a)
        objs.append(o["achieved_goal"].copy())
        grips.append(o["observation"][:3].copy())
        touch.append(n)
        tilt = max(tilt, _tilt(o))
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
            "object_yaw_change_deg": math.degrees(abs(_wrap(_yaw(o) - yaw0))),
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
            row[_key(s)] = {"distance_cm": round(100 * float(np.linalg.norm(p1[:2] - p0[:2])), 4),
                            "below_5pct_v0_s": slow, "below_1mm_s_s": stop,
                            "z_change_mm": round(1e3 * float(p1[2] - p0[2]), 4),
                            "lateral_mm": round(1e3 * float(abs(p1[0] - p0[0])), 4)}
        out["rows"].append(row)
    return out


class PushController:
    """A closed-loop scripted push, the same on both simulators: up, behind the object (as seen
    from the goal), down to the object's height, push until the object is at the goal."""

    def __init__(self) -> None:
        self.phase = "approach"

    def __call__(self, o: dict[str, np.ndarray]) -> np.ndarray:
        grip, obj, goal = o["observation"][:3], o["achieved_goal"], o["desired_goal"]
        d = goal[:2] - obj[:2]
        dist = float(np.linalg.norm(d))
        if dist < 0.01:
            return np.zeros(4, dtype=np.float32)
        u = d / dist
        behind = obj[:2] - u * 0.055
        high, low = obj[2] + 0.06, obj[2]
        rel = grip[:2] - obj[:2]
        off_line = abs(float(u[0] * rel[1] - u[1] * rel[0]))
        if self.phase == "push" and (off_line > 0.02 or float(u @ rel) > -0.02):
            self.phase = "approach"
        target = np.r_[behind, high]
        if self.phase == "approach":
            if np.linalg.norm(grip[:2] - behind) < 0.01:
                self.phase = "descend"
            elif grip[2] < obj[2] + 0.045:
                target = np.r_[grip[:2], high]
        if self.phase == "descend":
            target = np.r_[behind, low]
            if abs(grip[2] - low) < 0.008:
                self.phase = "push"
        if self.phase == "push":
            target = np.r_[goal[:2] - u * 0.0385, low]
        a = np.clip((target - grip) / 0.035, -1, 1)
        return np.r_[a, 0.0].astype(np.float32)


def rollouts(sims: Sequence[Sim], kind: str, episodes: int, matched: bool,
             seed0: int) -> dict[str, Any]:
    """`episodes` episodes of the scripted push (`kind` 'scripted') or of uniform random actions
    ('random', one seeded sequence per episode for every simulator), from matched states (the
    others set to the first's) or from each env's own reset with the same seed."""
    T = sims[0].env.spec.max_episode_steps
    per: dict[str, list[dict[str, Any]]] = {_key(s): [] for s in sims}
    div_grip = {_key(s): np.zeros((episodes, T)) for s in sims[1:]}
    div_obj = {_key(s): np.zeros((episodes, T)) for s in sims[1:]}
    mismatches = 0
    for ep in range(episodes):
        seed = seed0 + ep
        actions = np.random.default_rng(10_000 + seed).uniform(-1, 1, size=(T, 4))
        if matched:
            start_all(sims, seed)
        trajs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for s in sims:
            o = s.obs() if matched else s.env.reset(seed=seed)[0]
            ctl = PushController()
            obj0, yaw0 = o["achieved_goal"].copy(), _yaw(o)
            grips, objs, touch = [], [], []
            first_success, success, tilt, gtilt = -1, False, 0.0, []
            for t in range(T):
                o, r, success, n = s.step(ctl(o) if kind == "scripted" else actions[t])
                grips.append(o["observation"][:3].copy())
                objs.append(o["achieved_goal"].copy())
                touch.append(n > 0)
                if success and first_success < 0:
                    first_success = t + 1
                ours = float(fetch_reward(o["achieved_goal"], o["desired_goal"],
                                          s.u.distance_threshold))
                mismatches += (r != ours) + (success != (r == 0.0))
                tilt = max(tilt, _tilt(o))
                gtilt.append(s.gripper_tilt())
            g, ob = np.array(grips), np.array(objs)
            trajs[_key(s)] = (g, ob)
            path = np.linalg.norm(np.diff(np.vstack([obj0, ob])[:, :2], axis=0), axis=1)
            gpath = np.linalg.norm(np.diff(np.vstack([g[:1], g])[:, :2], axis=0), axis=1)
            t_idx = [i for i in range(T) if touch[i]]
            gp = float(gpath[t_idx].sum()) if t_idx else 0.0
            after = _slide_after(np.vstack([obj0, ob]), [False, *touch])
            per[_key(s)].append({
                "success": success, "first_success": first_success,
                "object_touched": bool(any(touch)),
                "object_moved_1cm": bool(np.linalg.norm(ob[-1, :2] - obj0[:2]) > 0.01),
                "object_displacement_cm": 100 * float(np.linalg.norm(ob[-1, :2] - obj0[:2])),
                "object_path_cm": 100 * float(path.sum()),
                "touching_steps": int(sum(touch)),
                "object_per_gripper_path_touching": (float(path[t_idx].sum()) / gp
                                                     if gp > 1e-6 else None),
                "slide_after_contact_mm": after[0], "steps_moving_after_contact": after[1],
                "object_yaw_change_deg": math.degrees(abs(_wrap(_yaw(o) - yaw0))),
                "object_toppled": bool(math.degrees(tilt) > 30),
                "object_off_table": bool(ob[-1, 2] < s.u.height_offset - 0.05),
                "final_goal_distance_cm": 100 * float(np.linalg.norm(ob[-1] - o["desired_goal"])),
                "gripper_step_mm": 1e3 * float(np.mean(gpath)),
                "gripper_tilt_mean_deg": float(np.mean(gtilt)),
                "gripper_tilt_max_deg": float(np.max(gtilt)),
            })
        if matched:
            g1, o1 = trajs[_key(sims[0])]
            for key, (g, ob) in list(trajs.items())[1:]:
                div_grip[key][ep] = np.linalg.norm(g - g1, axis=1)
                div_obj[key][ep] = np.linalg.norm(ob - o1, axis=1)
    out: dict[str, Any] = {"kind": kind, "matched": matched, "episodes": episodes,
                           "reward_mismatches": int(mismatches),
                           "by_sim": {key: _summary(rows) for key, rows in per.items()}}
    if matched:
        steps = [t for t in (1, 2, 5, 10, 20, 30, T) if t <= T]
        out["divergence_vs_first"] = {}
        for key in div_grip:
            dg, do = div_grip[key], div_obj[key]
            first = [int(np.argmax(row > 0.01)) + 1 if (row > 0.01).any() else None
                     for row in do]
            apart = [f for f in first if f is not None]
            out["divergence_vs_first"][key] = {
                "steps": steps,
                "gripper_median_mm": [round(1e3 * float(np.median(dg[:, t - 1])), 4)
                                      for t in steps],
                "gripper_max_mm": [round(1e3 * float(dg[:, t - 1].max()), 4) for t in steps],
                "object_median_mm": [round(1e3 * float(np.median(do[:, t - 1])), 4)
                                     for t in steps],
                "object_max_mm": [round(1e3 * float(do[:, t - 1].max()), 4) for t in steps],
                "episodes_object_apart_1cm": len(apart),
                "median_first_step_object_apart_1cm": float(np.median(apart)) if apart else None,
                "final_success_agree": round(float(np.mean([
                    a["success"] == b["success"] for a, b in zip(
                        per[_key(sims[0])], per[key], strict=True)])), 4),
            }
    return out


def _slide_after(ob: np.ndarray, touch: list[bool]) -> tuple[float | None, float | None]:
    """Object travel (mm) and steps moving (> 0.5 mm) after each contact ends, until the next
    contact or the episode's end; means over contact ends, None where contact never ended.
    `ob[t]` is the object after step t (ob[0] the start), `touch[t]` whether step t touched."""
    dists, steps = [], []
    T = len(touch)
    for t in range(1, T - 1):
        if touch[t] and not touch[t + 1]:
            end = next((j for j in range(t + 1, T) if touch[j]), T)
            seg = ob[t:end, :2]
            dists.append(1e3 * float(np.linalg.norm(seg[-1] - seg[0])))
            steps.append(int(np.sum(np.linalg.norm(np.diff(seg, axis=0), axis=1) > 5e-4)))
    if not dists:
        return None, None
    return round(float(np.mean(dists)), 3), round(float(np.mean(steps)), 3)


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Means over episodes (of those where a value exists); yes/no metrics as shares, with
    their counts under `counts`."""
    out: dict[str, Any] = {}
    counts: dict[str, str] = {}
    for k in rows[0]:
        vals = [r[k] for r in rows
                if r[k] is not None and not (k == "first_success" and r[k] < 0)]
        out[k] = round(float(np.mean(vals)), 4) if vals else None
        if isinstance(rows[0][k], bool):
            counts[k] = f"{sum(vals)}/{len(rows)}"
    out["n"] = len(rows)
    out["counts"] = counts
    return out


def weld_sweep(s1: Sim, task: str, values: Sequence[float], episodes: int) -> dict[str, Any]:
    """v4 with the mocap weld's torquescale at each of `values` (1 is v4's default) against v1:
    the gripper's tilt and step length under random actions (matched states) and the largest
    per-step difference from v1 in the free-space tracking sequence."""
    sims = [s1]
    for v in values:
        sims.append(make_v4_variant(task, f"torquescale={v:g}")[0])
    ro = rollouts(sims, "random", episodes, matched=True, seed0=2000)
    gt = gripper_tracking(sims)
    rows = []
    for s in sims:
        b = ro["by_sim"][_key(s)]
        rows.append({"sim": _key(s),
                     "gripper_tilt_mean_deg": b["gripper_tilt_mean_deg"],
                     "gripper_tilt_max_deg": b["gripper_tilt_max_deg"],
                     "gripper_step_mm": b["gripper_step_mm"],
                     "tracking_max_step_diff_from_v1_mm": gt["max_per_step_diff_mm"].get(
                         _key(s), 0.0)})
    for s in sims[1:]:
        s.env.close()
    ref = rows[0]["gripper_tilt_mean_deg"]
    best = min(rows[1:], key=lambda r: abs(r["gripper_tilt_mean_deg"] - ref))
    return {"episodes": episodes, "rows": rows, "closest_tilt_to_v1": best["sim"]}


def switch_check(s4: Sim, task: str, names: Sequence[str], episodes: int) -> dict[str, Any]:
    """MuJoCo 3 engine switches that MuJoCo 2.1 did not have, turned off one at a time: how far
    the scripted push (matched states) moves from v4's default, at most over all steps."""
    sims = [s4] + [make_v4_variant(task, n)[0] for n in names]
    ro = rollouts(sims, "scripted", episodes, matched=True, seed0=3000)
    out: dict[str, Any] = {"episodes": episodes, "rows": []}
    for n in names:
        dv = ro["divergence_vs_first"][f"v4:{n}"]
        out["rows"].append({
            "variant": n, "description": apply_variant_description(n),
            "gripper_max_diff_mm": max(dv["gripper_max_mm"]),
            "object_max_diff_mm": max(dv["object_max_mm"]),
            "success": ro["by_sim"][f"v4:{n}"]["success"],
            "success_v4": ro["by_sim"]["v4"]["success"]})
    for s in sims[1:]:
        s.env.close()
    return out


def apply_variant_description(name: str) -> str:
    return {"legacy-ccd": "native and multi-point CCD off",
            "no-island": "constraint islands off",
            "ls-tight": "Newton line search tolerance 1e-6, 100 iterations"}.get(name, name)
