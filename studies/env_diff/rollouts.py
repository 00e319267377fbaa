"""3 (d, e). Scripted and random rollouts in both simulators, from matched initial states (v4
set to v1's full simulator state after the same reset) and from each env's own reset: success,
object motion, contacts, and the per-step divergence of gripper and object between them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from hercs.rl.task_registry import fetch_reward
from studies.env_diff.dynamics import (
    gripper_tracking,
    object_tilt,
    object_yaw,
    sim_key,
    start_all,
    wrap_angle,
)
from studies.env_diff.sim import Sim, make_v4_variant


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
    per: dict[str, list[dict[str, Any]]] = {sim_key(s): [] for s in sims}
    div_grip = {sim_key(s): np.zeros((episodes, T)) for s in sims[1:]}
    div_obj = {sim_key(s): np.zeros((episodes, T)) for s in sims[1:]}
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
            obj0, yaw0 = o["achieved_goal"].copy(), object_yaw(o)
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
                tilt = max(tilt, object_tilt(o))
                gtilt.append(s.gripper_tilt())
            g, ob = np.array(grips), np.array(objs)
            trajs[sim_key(s)] = (g, ob)
            path = np.linalg.norm(np.diff(np.vstack([obj0, ob])[:, :2], axis=0), axis=1)
            gpath = np.linalg.norm(np.diff(np.vstack([g[:1], g])[:, :2], axis=0), axis=1)
            t_idx = [i for i in range(T) if touch[i]]
            gp = float(gpath[t_idx].sum()) if t_idx else 0.0
            after = _slide_after(np.vstack([obj0, ob]), [False, *touch])
            per[sim_key(s)].append({
                "success": success, "first_success": first_success,
                "object_touched": bool(any(touch)),
                "object_moved_1cm": bool(np.linalg.norm(ob[-1, :2] - obj0[:2]) > 0.01),
                "object_displacement_cm": 100 * float(np.linalg.norm(ob[-1, :2] - obj0[:2])),
                "object_path_cm": 100 * float(path.sum()),
                "touching_steps": int(sum(touch)),
                "object_per_gripper_path_touching": (float(path[t_idx].sum()) / gp
                                                     if gp > 1e-6 else None),
                "slide_after_contact_mm": after[0], "steps_moving_after_contact": after[1],
                "object_yaw_change_deg": math.degrees(abs(wrap_angle(object_yaw(o) - yaw0))),
                "object_toppled": bool(math.degrees(tilt) > 30),
                "object_off_table": bool(ob[-1, 2] < s.u.height_offset - 0.05),
                "final_goal_distance_cm": 100 * float(np.linalg.norm(ob[-1] - o["desired_goal"])),
                "gripper_step_mm": 1e3 * float(np.mean(gpath)),
                "gripper_tilt_mean_deg": float(np.mean(gtilt)),
                "gripper_tilt_max_deg": float(np.max(gtilt)),
            })
        if matched:
            g1, o1 = trajs[sim_key(sims[0])]
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
                        per[sim_key(sims[0])], per[key], strict=True)])), 4),
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
        b = ro["by_sim"][sim_key(s)]
        rows.append({"sim": sim_key(s),
                     "gripper_tilt_mean_deg": b["gripper_tilt_mean_deg"],
                     "gripper_tilt_max_deg": b["gripper_tilt_max_deg"],
                     "gripper_step_mm": b["gripper_step_mm"],
                     "tracking_max_step_diff_from_v1_mm": gt["max_per_step_diff_mm"].get(
                         sim_key(s), 0.0)})
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
