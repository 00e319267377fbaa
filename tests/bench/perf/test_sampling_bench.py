"""bench/perf/sampling.py --quick: every method measured, the reference draw has the same law."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from tests.support import REPO, load_module


def test_quick_mode_reports_every_method_and_part(tmp_path: Path) -> None:
    out = tmp_path / "sampling"
    done = subprocess.run([sys.executable, "-m", "bench.perf.sampling", "--quick",
                           "--out", str(out)], cwd=REPO, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["episodes"] == 500 and report["batch"] == 256 and report["k"] == 8
    assert set(report["results"]) == {"her", "her-cs", "her-ebp", "her-ebp-cs"}
    for row in report["results"].values():
        for part in ("draw", "relabel", "draw+relabel", "reference draw", "with inserts"):
            assert 0 < row[f"{part} p50"] <= row[f"{part} p99"], part
        assert row["draw ratio p50"] == row["draw p50"] / row["reference draw p50"]
    assert "| her-ebp-cs |" in out.with_suffix(".md").read_text()


def test_reference_draw_has_the_samplers_law() -> None:
    """The baseline is the same distribution: per-cluster draw counts of the reference and
    of the HER-CS sampler agree on average (the plan is deterministic, fills are uniform)."""
    bench = load_module("bench.perf.sampling")
    store, config = bench.fill_store(600)
    sampler = bench.make_sampler("her-cs", bench.apply_overrides(
        config, ["run.method=her-cs"]).sampler_settings)
    rng = np.random.default_rng(0)
    ours = np.zeros(bench.K)
    ref = np.zeros(bench.K)
    for _ in range(300):
        ours += np.bincount(store.cluster[sampler.sample(store, 256, rng)[0]],
                            minlength=bench.K)
        ref += np.bincount(store.cluster[bench.reference_draw(
            "her-cs", store, epsilon=1e-6, repeat=4, rng=rng)], minlength=bench.K)
    np.testing.assert_allclose(ours / 300, ref / 300, atol=1.0)
