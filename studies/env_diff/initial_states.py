"""2. Initial states: resets of both versions with the same seeds, and how far things drift
under zero actions."""

from __future__ import annotations

from typing import Any

import numpy as np

from studies.env_diff.sim import Sim, json_value


def _stats(a: np.ndarray) -> dict[str, list[float]]:
    return {k: [round(float(v), 5) for v in np.atleast_1d(f(a, axis=0))]
            for k, f in (("mean", np.mean), ("std", np.std), ("min", np.min), ("max", np.max))}


def initial_states(s1: Sim, s4: Sim, n: int, still_episodes: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    recs: dict[str, dict[str, list[Any]]] = {}
    for s in (s1, s4):
        r: dict[str, list[Any]] = {k: [] for k in ("obj", "goal", "grip", "d0", "obj_pen",
                                                   "finger_pen", "grip_speed", "contacts")}
        for seed in range(n):
            o, _ = s.env.reset(seed=seed)
            top = s.table_top()
            r["obj"].append(o["achieved_goal"])
            r["goal"].append(o["desired_goal"])
            r["grip"].append(o["observation"][:3])
            r["d0"].append(float(np.linalg.norm(o["achieved_goal"] - o["desired_goal"])))
            half = float(s.model.geom_size[s.object_geom][2 if int(
                s.model.geom_type[s.object_geom]) == 6 else 1])
            r["obj_pen"].append(top - (float(o["achieved_goal"][2]) - half))
            r["finger_pen"].append(top - min(s.geom_bottom(g) for g in s.finger_geoms))
            r["grip_speed"].append(float(np.linalg.norm(o["observation"][20:23])) / s.u.dt)
            r["contacts"].append(s.contact_counts())
        recs[s.version] = r
        d0 = np.array(r["d0"])
        out[s.version] = {
            "initial_gripper_xpos": json_value(s.u.initial_gripper_xpos),
            "height_offset": json_value(s.u.height_offset),
            "object_xy": _stats(np.array(r["obj"])[:, :2]),
            "goal_xyz": _stats(np.array(r["goal"])),
            "gripper_xyz": _stats(np.array(r["grip"])),
            "object_goal_distance": _stats(d0),
            "share_goal_within_5cm": float(np.mean(d0 < 0.05)),
            "object_table_penetration_mm": round(1e3 * float(np.mean(r["obj_pen"])), 3),
            "finger_table_penetration_mm": round(1e3 * float(np.mean(r["finger_pen"])), 3),
            "gripper_speed_at_reset_m_s": round(float(np.mean(r["grip_speed"])), 5),
            "contacts_at_reset": {k: round(float(np.mean([c[k] for c in r["contacts"]])), 2)
                                  for k in r["contacts"][0]},
        }
    # same seed, same draws: the object/goal offsets from the initial gripper are the same
    a, b = recs["v1"], recs["v4"]
    off1 = np.array(a["obj"])[:, :2] - s1.u.initial_gripper_xpos[:2]
    off4 = np.array(b["obj"])[:, :2] - s4.u.initial_gripper_xpos[:2]
    g1 = np.array(a["goal"]) - np.r_[s1.u.initial_gripper_xpos[:2], s1.u.height_offset]
    g4 = np.array(b["goal"]) - np.r_[s4.u.initial_gripper_xpos[:2], s4.u.height_offset]
    out["paired"] = {
        "resets": n,
        "object_offset_max_abs_diff_m": float(np.abs(off1 - off4).max()),
        "goal_offset_max_abs_diff_m": float(np.abs(g1[:, :2] - g4[:, :2]).max()),
        "goal_in_air_share": {v: float(np.mean(np.array(recs[v]["goal"])[:, 2]
                                               > (u.height_offset + 1e-6)))
                              for v, u in (("v1", s1.u), ("v4", s4.u))},
        "object_goal_distance_max_abs_diff_m": float(np.abs(np.array(a["d0"])
                                                            - np.array(b["d0"])).max()),
        "initial_gripper_xpos_diff_m": json_value(s1.u.initial_gripper_xpos
                                            - s4.u.initial_gripper_xpos),
        "same_success_at_reset": float(np.mean((np.array(a["d0"]) < 0.05)
                                               == (np.array(b["d0"]) < 0.05))),
    }
    out["still"] = still_rollouts(s1, s4, still_episodes)
    return out


def still_rollouts(s1: Sim, s4: Sim, episodes: int) -> dict[str, Any]:
    """Zero actions for a whole episode: how far gripper and object drift by themselves."""
    out: dict[str, Any] = {}
    zero = np.zeros(4, dtype=np.float32)
    for s in (s1, s4):
        obj_drift, grip_first, grip_rest, obj_z, success_change = [], [], [], [], 0
        for seed in range(episodes):
            o, _ = s.env.reset(seed=seed)
            obj0, grip0 = o["achieved_goal"].copy(), o["observation"][:3].copy()
            ok0 = bool(np.linalg.norm(obj0 - o["desired_goal"]) < 0.05)
            ok, grip1 = ok0, grip0
            for t in range(s.env.spec.max_episode_steps):
                o, _, ok, _ = s.step(zero)
                if t == 0:
                    grip_first.append(o["observation"][:3] - grip0)
                    grip1 = o["observation"][:3].copy()
            grip_rest.append(float(np.linalg.norm(o["observation"][:3] - grip1)))
            obj_drift.append(float(np.linalg.norm(o["achieved_goal"][:2] - obj0[:2])))
            obj_z.append(float(o["achieved_goal"][2] - obj0[2]))
            success_change += ok != ok0
        out[s.version] = {
            "episodes": episodes,
            "gripper_first_step_mm": json_value(1e3 * np.mean(grip_first, axis=0)),
            "gripper_drift_after_first_step_mm": round(1e3 * float(np.mean(grip_rest)), 3),
            "object_xy_drift_mm": round(1e3 * float(np.mean(obj_drift)), 4),
            "object_z_change_mm": round(1e3 * float(np.mean(obj_z)), 4),
            "success_changed_episodes": success_change,
        }
    return out
