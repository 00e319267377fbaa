"""The report: the versions, the kept conclusion and the markdown of every task's comparison."""

from __future__ import annotations

import importlib.metadata
from typing import Any


def versions() -> dict[str, str]:
    import mujoco
    from mujoco_py import functions

    out = {"mujoco": mujoco.__version__}
    for dist in ("mujoco-py-cython3", "gymnasium-robotics", "gymnasium"):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = "not installed"
    v = int(functions.mj_version())
    out["MuJoCo under mujoco-py"] = f"{v // 100}.{v // 10 % 10}.{v % 10}"
    return out


def _fmt(v: Any) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        if len(v) > 6 and all(not isinstance(x, list) for x in v):
            return "[" + " ".join(_fmt(x) for x in v[:6]) + " …]"
        return "[" + " ".join(_fmt(x) for x in v) + "]"
    return str(v)


CONCLUSION_HEADING = "## What differs, and what may matter to learning"
"""The heading of the reading of the committed full run, written by hand after it in
docs/results/env_diff.md; a regenerated full report keeps it above the tables (not --quick)."""


def render_md(result: dict[str, Any], conclusion: str = "") -> str:
    """The report of `result`, with `conclusion` (the kept reading, `kept_findings`) above
    the tables of a full run."""
    L: list[str] = []
    add = L.append
    add("# Fetch*-v1 (mujoco-py, MuJoCo 2.1) against Fetch*-v4 (MuJoCo 3)")
    add("")
    add(f"`{result['command']}` — {result['date']}, commit {result['commit']}, "
        f"{result['machine']['cpu']}.")
    add("")
    add("Versions: " + ", ".join(f"{k} {v}" for k, v in result["versions"].items()) + ".")
    add("")
    add("Both versions load gymnasium-robotics' XML assets (identical to gym 0.21's "
        "`envs/robotics/assets/fetch`) and run the same task code; v1 steps them with "
        "mujoco-py on MuJoCo 2.1.0, v4 with the mujoco bindings.")
    add("")
    if not result.get("quick") and conclusion:
        add(CONCLUSION_HEADING)
        add("")
        add(conclusion.strip())
        add("")
    for task, res in result["tasks"].items():
        L.extend(_task_md(task, res))
    return "\n".join(L) + "\n"


def _task_md(task: str, res: dict[str, Any]) -> list[str]:
    L: list[str] = []
    add = L.append
    add(f"## {res['env_ids'][0]} against {res['env_ids'][1]}")
    add("")
    if res["variants"]:
        add("v4 variants: " + "; ".join(f"`v4:{k}`: {v}" for k, v in res["variants"].items()))
        add("")
    add("### 1. Models")
    add("")
    rows = res["options"] + res["params"]
    diff = [r for r in rows if not r["equal"]]
    same = [r for r in rows if r["equal"]]
    add("Parameters that differ (or exist in one version only):")
    add("")
    add("| group | parameter | v1 | v4 | note |")
    add("|---|---|---|---|---|")
    for r in diff:
        add(f"| {r['group']} | {r['param']} | {_fmt(r['v1'])} | {_fmt(r['v4'])} | {r['note']} |")
    add("")
    add(f"Equal in both ({len(same)}): " + "; ".join(
        f"{r['param']} = {_fmt(r['v1'])}" for r in same) + ".")
    add("")
    af = res["all_fields"]
    add(f"Every numeric mjModel field both bindings expose: {af['equal_fields']} equal, "
        f"{len(af['differ'])} differ, {len(af['shape_differs'])} differ in shape "
        f"({af['only_v1']} fields only mujoco-py exposes, {af['only_v4']} only MuJoCo 3 has):")
    add("")
    add("| field | elements differing | max abs diff | first (index: v1 → v4) | what |")
    add("|---|---|---|---|---|")
    for d in af["differ"]:
        f = d["first"]
        add(f"| {d['field']} | {d['elements']} | {d['max_abs_diff']:.3g} | "
            f"{f['index']}: {_fmt(f['v1'])} → {_fmt(f['v4'])} | {d['note']} |")
    for d in af["shape_differs"]:
        add(f"| {d['field']} | shape {d['v1']} → {d['v4']} | | | {d['note']} |")
    mc = af["meshes"]
    add("")
    add(f"Mesh geoms in their bodies' frames: bounding boxes agree within "
        f"{1e3 * mc['body_frame_bbox_max_diff_m']:.3g} mm; distinct vertex counts match: "
        f"{mc['distinct_vertices_match']}.")
    add("")
    ini = res["initial"]
    add(f"### 2. Initial states ({ini['paired']['resets']} resets, seeds 0..N-1)")
    add("")
    add("| | v1 | v4 |")
    add("|---|---|---|")
    for k, label in (("initial_gripper_xpos", "initial gripper (grip site) after setup"),
                     ("height_offset", "object resting height (goal z on the table)")):
        add(f"| {label} | {_fmt(ini['v1'][k])} | {_fmt(ini['v4'][k])} |")
    for k, label in (("object_xy", "object xy"), ("goal_xyz", "goal xyz"),
                     ("gripper_xyz", "gripper xyz"),
                     ("object_goal_distance", "object–goal distance")):
        for stat in ("mean", "std", "min", "max"):
            add(f"| {label} {stat} | {_fmt(ini['v1'][k][stat])} | {_fmt(ini['v4'][k][stat])} |")
    for k, label in (("share_goal_within_5cm", "share of goals within 5 cm at reset"),
                     ("object_table_penetration_mm", "object into table (mm)"),
                     ("finger_table_penetration_mm", "fingers into table (mm; < 0: above)"),
                     ("gripper_speed_at_reset_m_s", "gripper speed at reset (m/s)")):
        add(f"| {label} | {_fmt(ini['v1'][k])} | {_fmt(ini['v4'][k])} |")
    add(f"| contacts at reset | {_fmt(ini['v1']['contacts_at_reset'])} | "
        f"{_fmt(ini['v4']['contacts_at_reset'])} |")
    st = ini["still"]
    for k, label in (("gripper_first_step_mm", "zero action: gripper's first step (mm)"),
                     ("gripper_drift_after_first_step_mm", "zero action: gripper drift after"),
                     ("object_xy_drift_mm", "zero action: object xy drift (mm)"),
                     ("object_z_change_mm", "zero action: object z change (mm)"),
                     ("success_changed_episodes", "zero action: episodes whose success "
                      "changed")):
        add(f"| {label} ({st['v1']['episodes']} episodes) | {_fmt(st['v1'][k])} | "
            f"{_fmt(st['v4'][k])} |")
    for xt in ini["v4_xml"]:
        what = f"torquescale {xt['torquescale']:g}" + (", native/multi CCD off"
                                                      if xt["legacy_ccd"] else "")
        add(f"| v4 built from its XML with {what}: initial gripper / object resting height / "
            f"object–table contacts | | {_fmt(xt['initial_gripper_xpos'])} / "
            f"{_fmt(xt['height_offset'])} / {xt['object_table_contacts']} |")
    p = ini["paired"]
    add("")
    add(f"Same seed, same draws: object offsets from the initial gripper differ by at most "
        f"{p['object_offset_max_abs_diff_m']:.2g} m, goal offsets by "
        f"{p['goal_offset_max_abs_diff_m']:.2g} m, object–goal distances by "
        f"{p['object_goal_distance_max_abs_diff_m']:.2g} m; success at reset agrees in "
        f"{100 * p['same_success_at_reset']:.0f} % of resets. The whole distribution is "
        f"shifted by the initial gripper's difference {_fmt(p['initial_gripper_xpos_diff_m'])}"
        f" m (v1 − v4). Goals in the air: {_fmt(p['goal_in_air_share'])}.")
    add("")
    dyn = res["dynamics"]
    keys = list(dyn["scripted_matched"]["by_sim"])
    add("### 3. Dynamics under the same actions")
    add("")
    add(f"The comparison steps each env substep by substep (to see contacts inside a step); "
        f"against env.step from the same state its observations differ by at most "
        f"{_fmt(dyn['step_replica_max_diff'])} (0: bit for bit).")
    add("")
    gt = dyn["gripper_tracking"]
    add("Free-space gripper tracking (mm per step at steady state, after a lift):")
    add("")
    labels = list(gt["v1"]["steady_mm_per_step"])
    add("| | " + " | ".join(labels) + " | coast after stop (mm) |")
    add("|---|" + "---|" * (len(labels) + 1))
    for k in keys:
        add(f"| {k} | " + " | ".join(_fmt(gt[k]["steady_mm_per_step"][x]) for x in labels)
            + f" | {_fmt(gt[k]['coast_after_stop_mm'])} |")
    add("")
    add(f"Largest per-step difference from v1 (mm): {_fmt(gt['max_per_step_diff_mm'])}.")
    add("")
    pp = dyn["push_probe"]
    add("Controlled push (object 6 cm in front of the fingers along ±y, pushed ~12 cm, gripper "
        "withdrawn; same state in every simulator; mean over seeds and both directions):")
    add("")
    metrics = list(next(iter(pp["v1"].values())))
    add("| sim | speed | " + " | ".join(metrics) + " |")
    add("|---|---|" + "---|" * len(metrics))
    for k in keys:
        for mag, row in pp[k].items():
            add(f"| {k} | {mag} | " + " | ".join(_fmt(row[m]) for m in metrics) + " |")
    add("")
    sp = dyn["slide_probe"]
    add(f"Free slide (object launched along +y, substeps; μ = {sp['mu']:g}):")
    add("")
    add("| v0 (m/s) | Coulomb: cm / stop s | " + " | ".join(
        f"{k}: cm / below 5 % of v0 (s) / below 1 mm/s (s) / lateral mm" for k in keys) + " |")
    add("|---|---|" + "---|" * len(keys))
    for r in sp["rows"]:
        add(f"| {r['v0_m_s']} | {r['coulomb_cm']} / {r['coulomb_stop_s']} | " + " | ".join(
            f"{_fmt(r[k]['distance_cm'])} / {_fmt(r[k]['below_5pct_v0_s'])} / "
            f"{_fmt(r[k]['below_1mm_s_s'])} / "
            f"{_fmt(r[k]['lateral_mm'])}" for k in keys) + " |")
    add("")
    for kind in ("scripted", "random"):
        for m in ("matched", "own"):
            ro = dyn[f"{kind}_{m}"]
            what = ("scripted closed-loop push" if kind == "scripted"
                    else "uniform random actions")
            start = ("matched initial states (v4 set to v1's)" if m == "matched"
                     else "each env's own reset, same seeds")
            add(f"{what.capitalize()}, {start}, {ro['episodes']} episodes "
                f"(reward/success mismatches: {ro['reward_mismatches']}):")
            add("")
            ms = [x for x in ro["by_sim"]["v1"] if x not in ("n", "counts")]
            add("| sim | " + " | ".join(ms) + " |")
            add("|---|" + "---|" * len(ms))
            for k in keys:
                b = ro["by_sim"][k]
                add(f"| {k} | " + " | ".join(
                    _fmt(b[x]) + (f" ({b['counts'][x]})" if x in b["counts"] else "")
                    for x in ms) + " |")
            add("")
            if m == "matched":
                for k, dv in ro["divergence_vs_first"].items():
                    add(f"Divergence of {k} from v1 at steps {dv['steps']}: gripper median "
                        f"{_fmt(dv['gripper_median_mm'])} mm (max {_fmt(dv['gripper_max_mm'])});"
                        f" object median {_fmt(dv['object_median_mm'])} mm (max "
                        f"{_fmt(dv['object_max_mm'])}); objects 1 cm apart in "
                        f"{dv['episodes_object_apart_1cm']}/{ro['episodes']} episodes, median "
                        f"first step {_fmt(dv['median_first_step_object_apart_1cm'])}.")
                    add("")
    ws = res["weld_sweep"]
    add(f"Mocap weld torquescale on v4 against v1 (uniform random actions, {ws['episodes']} "
        "episodes from matched states; tracking: the free-space sequence above):")
    add("")
    add("| sim | gripper tilt mean (deg) | tilt max (deg) | gripper step (mm) | tracking: largest "
        "per-step difference from v1 (mm) |")
    add("|---|---|---|---|---|")
    for r in ws["rows"]:
        add(f"| {r['sim']} | {_fmt(r['gripper_tilt_mean_deg'])} | "
            f"{_fmt(r['gripper_tilt_max_deg'])} | {_fmt(r['gripper_step_mm'])} | "
            f"{_fmt(r['tracking_max_step_diff_from_v1_mm'])} |")
    add("")
    add(f"Closest mean tilt to v1: {ws['closest_tilt_to_v1']}.")
    add("")
    sw = res["switches"]
    add(f"MuJoCo 3 engine switches turned off one at a time (scripted push, {sw['episodes']} "
        "episodes from matched states, against v4's default):")
    add("")
    add("| switch | what | gripper: largest difference (mm) | object: largest difference (mm) "
        "| success (v4 default) |")
    add("|---|---|---|---|---|")
    for r in sw["rows"]:
        add(f"| {r['variant']} | {r['description']} | {_fmt(r['gripper_max_diff_mm'])} | "
            f"{_fmt(r['object_max_diff_mm'])} | {_fmt(r['success'])} "
            f"({_fmt(r['success_v4'])}) |")
    add("")
    rw = res["reward"]
    add("### 4. Reward and success")
    add("")
    add(f"On {rw['pairs']} random goal pairs (half within 4.5–5.5 cm): compute_reward equal: "
        f"{rw['compute_reward_equal']}; is_success equal: {rw['is_success_equal']}; equal to "
        f"hercs.rl.task_registry.fetch_reward: {rw['hercs_fetch_reward_equal']}; "
        "success iff reward 0: "
        f"{rw['success_iff_reward_zero']}; threshold {rw['distance_threshold']}, reward type "
        f"{rw['reward_type']}.")
    add("")
    return L
