"""studies/env_diff/offline_probe.py: both simulations get the same actions from the same resets
(the pairing the probe rests on), offline training is a function of its data and seed, the quick
mode fills every cell, and the committed report is what its JSON gives."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hercs.rl.envs import mujoco_py_problem
from hercs.rl.task_registry import task_spec
from studies.env_diff.offline_probe import FACTS, collect, random_actions, render, train
from tests.support import REPO

REPORT = REPO / "docs" / "results" / "offline_probe.json"


def test_the_same_actions_from_the_same_resets_and_reproducible_training() -> None:
    spec = task_spec("push")
    actions = random_actions(3, spec.episode_steps, spec.action_dim)
    np.testing.assert_array_equal(actions[0], random_actions(1, spec.episode_steps,
                                                             spec.action_dim)[0])
    data = collect("v4", actions)
    again = collect("v4", actions)
    assert [e.obs.shape for e in data] == [(spec.episode_steps + 1, spec.obs_dim)] * 3
    for a, b, acts in zip(data, again, actions, strict=True):
        np.testing.assert_array_equal(a.actions, acts.astype(np.float32))
        np.testing.assert_array_equal(a.obs, b.obs)  # MuJoCo is deterministic from a reset
    assert len({tuple(e.g[0]) for e in data}) == 3  # each reset seed its own goal
    one = train("v4", data, seed=1, cycles=1)
    same = train("v4", data, seed=1, cycles=1)
    other = train("v4", data, seed=2, cycles=1)
    for name, value in one.actor.items():
        np.testing.assert_array_equal(value, same.actor[name])
    assert any(not np.array_equal(v, other.actor[k]) for k, v in one.actor.items())
    np.testing.assert_array_equal(one.o_stats["mean"], same.o_stats["mean"])


def test_quick_mode_fills_every_cell(tmp_path: Path) -> None:
    sims = ["v4"] if mujoco_py_problem() else ["v1", "v4"]
    if len(sims) == 1:
        print(f"v1 not installed here ({mujoco_py_problem()}): the quick mode runs on v4 only")
    done = subprocess.run([sys.executable, "-m", "studies.env_diff.offline_probe", "--quick",
                           "--sims",
                           *sims, "--out", str(tmp_path)], cwd=REPO, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    result = json.loads((tmp_path / "offline_probe.json").read_text())
    assert sorted(result["data"]) == sorted(sims)
    assert len(result["policies"]) == len(sims)  # one seed
    for row in result["policies"]:
        assert sorted(row["acted_in"]) == sorted(sims)
        for facts in row["acted_in"].values():
            assert facts["episodes"] == 4
            assert all(math.isfinite(facts[k]) for k in FACTS)
    assert (tmp_path / "offline_probe.md").read_text() == render(result)


@pytest.mark.docs_check
def test_docs_check_the_committed_report_is_its_json_and_its_findings_quote_it() -> None:
    """A regeneration check (offline_probe.md is its json rendered) and a check of the
    findings' numbers against the data committed beside them, not a test of the code."""
    if not REPORT.exists():
        print("no committed docs/results/offline_probe.json yet: nothing to check")
        return
    result = json.loads(REPORT.read_text())
    assert REPORT.with_suffix(".md").read_text() == render(result)
    findings = result["findings"]
    for sim in ("v1", "v4"):
        assert f"{result['data'][sim]['moved_share']:.3f}".lstrip("0") in findings
        own = [p["acted_in"][sim] for p in result["policies"] if p["trained_on"] == sim]
        assert f"{np.mean([f['end_to_cube_m'] for f in own]):.3f} m" in findings
        assert f"{np.mean([f['travel_m'] for f in own]):.3f}" in findings
        for f in own:  # each seed's figure, as the text lists them
            assert f"{f['end_to_cube_m']:.3f}".lstrip("0") in findings
    across = max(abs(p["acted_in"]["v1"][k] - p["acted_in"]["v4"][k])
                 for p in result["policies"] for k in ("end_to_cube_m", "travel_m"))
    assert across <= 0.03, "the text says one policy's facts differ by at most 0.03 m"
