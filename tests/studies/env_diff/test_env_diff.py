"""python -m studies.env_diff --quick: FetchPush-v1 against FetchPush-v4 from a few resets and short
episodes; the result has the parameter table and the trajectory comparison, in finite numbers.
Skipped, with the reason, where the authors' v1 envs cannot run (no `make mujoco-py`)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

from tests.support import skip_without_mujoco_py

REPO = Path(__file__).resolve().parents[3]


def _numbers(x: Any) -> list[float]:
    if isinstance(x, bool):
        return []
    if isinstance(x, int | float):
        return [float(x)]
    if isinstance(x, dict):
        return [v for y in x.values() for v in _numbers(y)]
    if isinstance(x, list):
        return [v for y in x for v in _numbers(y)]
    return []


def test_quick_mode_compares_the_models_and_the_trajectories(tmp_path: Path) -> None:
    skip_without_mujoco_py()
    done = subprocess.run([sys.executable, "-m", "studies.env_diff", "--quick",
                           "--out", str(tmp_path / "diff")], cwd=REPO, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    result = json.loads((tmp_path / "diff.json").read_text())
    assert set(result["versions"]) >= {"mujoco", "mujoco-py-cython3", "gymnasium-robotics"}
    push = result["tasks"]["push"]
    assert push["env_ids"] == ["FetchPush-v1", "FetchPush-v4"]

    # the parameter table: every row names v1's and v4's value and whether they are equal
    rows = {r["param"]: r for r in push["options"] + push["params"]}
    assert rows["timestep (s)"]["v1"] == rows["timestep (s)"]["v4"] == 0.002
    assert rows["n_substeps"]["equal"] and rows["object0 geom friction"]["equal"]
    assert all({"v1", "v4", "equal"} <= set(r) for r in rows.values())
    assert push["all_fields"]["equal_fields"] > 100

    # the trajectory comparison from matched states: finite, and the same start for both
    dyn = push["dynamics"]
    assert dyn["step_replica_max_diff"]["v4"] == 0.0
    div = dyn["scripted_matched"]["divergence_vs_first"]["v4"]
    for key in ("gripper_median_mm", "object_median_mm", "gripper_max_mm", "object_max_mm"):
        assert len(div[key]) == len(div["steps"]) and all(math.isfinite(v) for v in div[key])
    for kind in ("scripted_matched", "scripted_own", "random_matched", "random_own"):
        assert set(dyn[kind]["by_sim"]) == {"v1", "v4"}
        assert dyn[kind]["reward_mismatches"] == 0
    for part in ("gripper_tracking", "push_probe", "slide_probe"):
        values = _numbers(dyn[part])
        assert values and all(math.isfinite(v) for v in values), part
    assert push["reward"]["compute_reward_equal"] and push["reward"]["is_success_equal"]
    assert "| group | parameter | v1 | v4 | note |" in (tmp_path / "diff.md").read_text()


def test_an_unknown_variant_is_refused_with_its_name() -> None:
    done = subprocess.run([sys.executable, "-m", "studies.env_diff", "--variant", "stiffer"],
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "unknown variant 'stiffer'" in done.stderr
