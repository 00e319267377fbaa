"""bench/perf/throughput/: its pure helpers (exact values) and its quick mode end to end.

No timing is asserted anywhere: the quick run only has to produce every figure, finite and
positive, with consistent ratios, in both the JSON and the markdown.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from bench.perf.throughput import BenchError
from bench.perf.throughput.plan import QUICK
from bench.perf.throughput.rates import percentile, pooled_rate, work_in_windows
from bench.perf.throughput.replay_memory import own_rss_mib
from bench.perf.throughput.throughput_report import (
    BELOW,
    MEETS,
    NO_TARGET,
    Figure,
    Target,
    figure_keys,
    format_value,
    markdown_table,
    parse_proc_status_kib,
    verdict,
)

REPO = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize(("values", "q", "expected"), [
    ([3.0], 99, 3.0),
    ([4, 1, 3, 2], 50, 2.5),
    ([10, 20, 30, 40, 50], 0, 10.0),
    ([10, 20, 30, 40, 50], 100, 50.0),
    ([10, 20, 30, 40, 50], 99, 49.6),    # position 3.96: 40 + 0.96 × 10
    ([10, 20, 30, 40, 50], 25, 20.0),
    (list(range(1, 101)), 99, 99.01),    # position 98.01: 99 + 0.01 × 1
], ids=["single", "median-even", "p0", "p100", "p99", "p25", "p99-of-100"])
def test_percentile_interpolates_between_closest_ranks(values, q, expected) -> None:
    assert percentile(values, q) == pytest.approx(expected, abs=1e-12)


def test_percentile_refuses_empty_input_and_bad_q() -> None:
    with pytest.raises(ValueError, match="no values"):
        percentile([], 50)
    with pytest.raises(ValueError, match="q=101"):
        percentile([1.0], 101)


def test_pooled_rate_counts_whole_intervals_inside_each_slice() -> None:
    # Slice 1: 5 episodes of 50 steps over 2 s (200 steps); slice 2: 3 over 1 s (100 steps);
    # a slice with a single arrival adds nothing. (200 + 100) / (2 + 1) = 100 steps/s: the
    # 8 s pause between the slices is never counted.
    first = [(10.0, 0), (10.5, 50), (11.0, 100), (11.5, 150), (12.0, 200)]
    second = [(20.5, 300), (20.0, 250), (21.0, 350)]  # order inside a slice does not matter
    assert pooled_rate([first, second, [(30.0, 400)]]) == 100.0
    with pytest.raises(BenchError, match="no slice of 2 holds two distinct arrivals"):
        pooled_rate([[(1.0, 0)], [(2.0, 5), (2.0, 9)]])


def test_work_in_windows_counts_work_finished_inside_each_window() -> None:
    # Cumulative steps at arrival times; windows (0.5, 2.5] and (3.5, 10]: 200 − 0 (nothing
    # before 0.5 counts as 0) and 400 − 300.
    samples = [(1.0, 100), (2.0, 200), (3.0, 300), (4.0, 400)]
    assert work_in_windows(samples, [(0.5, 2.5), (3.5, 10.0)]) == 300
    assert work_in_windows(samples, [(2.0, 3.0)]) == 100  # (start, end]: 300 − 200
    assert work_in_windows(samples, []) == 0


@pytest.mark.parametrize(("target", "ours", "ratio", "expected"), [
    (Target("ratio_at_least", 0.9), 900.0, 0.9, MEETS),
    (Target("ratio_at_least", 0.9), 899.0, 0.899, BELOW),
    (Target("ratio_at_most", 1.5), 150.0, 1.5, MEETS),
    (Target("ratio_at_most", 1.5), 151.0, 1.51, BELOW),
    (Target("ours_at_most", 5.0), 5.0, 40.0, MEETS),
    (Target("ours_at_most", 5.0), 5.01, 0.1, BELOW),
    (Target("ours_at_least", 1000.0), 1000.0, 0.1, MEETS),
    (Target("ours_at_least", 1000.0), 999.0, 10.0, BELOW),
    (None, 1.0, 1.0, NO_TARGET),
], ids=["ratio-min-met", "ratio-min-missed", "ratio-max-met", "ratio-max-missed",
        "ours-max-met", "ours-max-missed", "ours-min-met", "ours-min-missed", "none"])
def test_verdict_checks_the_bound_the_target_names(target, ours, ratio, expected) -> None:
    assert verdict(target, ours=ours, ratio=ratio) == expected


def test_target_text_names_the_bound() -> None:
    assert Target("ratio_at_least", 0.95).describe("updates/s") == "ratio ≥ 0.95"
    assert Target("ratio_at_most", 1.5).describe("MiB") == "ratio ≤ 1.5"
    assert Target("ours_at_most", 5.0).describe("ms") == "≤ 5.00 ms"
    assert Target("ours_at_least", 1000.0).describe("episodes/s") == "≥ 1,000 episodes/s"


@pytest.mark.parametrize(("value", "unit", "text"), [
    (1234.4, "steps/s", "1,234 steps/s"),
    (52.14, "updates/s", "52.1 updates/s"),
    (4.567, "ms", "4.57 ms"),
    (0.41934, "ms", "0.419 ms"),
    (0.0, "", "0"),
], ids=["thousands", "tens", "units", "below-one", "no-unit"])
def test_format_value(value, unit, text) -> None:
    assert format_value(value, unit) == text


def test_figure_ratio_verdict_and_table_row() -> None:
    figure = Figure(key="env", name="env steps/s, one actor", unit="steps/s", ours=900.0,
                       reference=1200.0, ours_what="actor", reference_what="raw",
                       target=Target("ratio_at_least", 0.9))
    row = figure.to_dict()
    assert row["ratio"] == 0.75 and row["verdict"] == BELOW
    assert row["target"] == {"kind": "ratio_at_least", "value": 0.9, "text": "ratio ≥ 0.9"}
    table = markdown_table([row]).splitlines()
    assert table[0] == "| figure | ours | reference | ratio | target | verdict |"
    assert table[2] == ("| env steps/s, one actor | 900 steps/s | 1,200 steps/s | 0.75× | "
                        "ratio ≥ 0.9 | below target |")


def test_proc_status_fields_are_read_in_kib() -> None:
    text = "Name:\tpython\nVmHWM:\t  204800 kB\nVmRSS:\t  102400 kB\nThreads:\t18\n"
    assert parse_proc_status_kib(text, "VmRSS") == 102400
    assert parse_proc_status_kib(text, "VmHWM") == 204800
    with pytest.raises(ValueError, match="RssShmem"):
        parse_proc_status_kib(text, "RssShmem")
    memory = {"VmRSS": 300.0, "RssShmem": 48.0}
    assert own_rss_mib(memory) == 252.0


def test_figure_keys_cover_every_phase() -> None:
    keys = figure_keys(actor_counts=(1, 2), methods=("her", "her-cs"), no_scene_counts=(2,))
    assert keys[:8] == ["env_steps_per_s", "env_steps_per_cpu_s", "learner_updates_per_s",
                        "learner_updates_per_cpu_s", "learner_roofline_fp32",
                        "learner_roofline_bf16", "inserts_per_s_1_actors",
                        "inserts_per_s_2_actors"]
    assert "sample_p99_minibatch_her-cs" in keys and "sample_p50_request_her" in keys
    assert keys[-3:] == ["replay_rss_growth", "replay_rss_total",
                         "inserts_per_s_2_actors_no_scene"]
    assert len(keys) == 6 + 2 + 2 * 4 + 2 + 1


@pytest.mark.full
@pytest.mark.integration
@pytest.mark.slow
def test_quick_mode_reports_every_figure(tmp_path: Path) -> None:
    """The whole benchmark on tiny sizes with real processes over Zenoh: every figure is in
    the JSON, finite and positive, ratio = ours / reference, and every row is in the
    markdown (which is also printed). No figure is compared with its target here."""
    out = tmp_path / "results"
    run = subprocess.run([sys.executable, "-m", "bench.perf.throughput", "--quick",
                          "--out", str(out)], capture_output=True, text=True, timeout=300,
                         cwd=REPO)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-5000:]
    report = json.loads((out / "throughput.json").read_text())
    markdown = (out / "throughput.md").read_text()
    assert run.stdout == markdown

    assert report["mode"] == "quick"
    plan = QUICK
    expected = figure_keys(actor_counts=plan.insert_actor_counts, methods=plan.methods,
                              no_scene_counts=plan.insert_no_scene_counts)
    figures = {f["key"]: f for f in report["figures"]}
    assert sorted(figures) == sorted(expected)
    for key, f in figures.items():
        for field in ("ours", "reference", "ratio"):
            assert math.isfinite(f[field]) and f[field] > 0, (key, field, f[field])
        assert f["ratio"] == pytest.approx(f["ours"] / f["reference"], rel=1e-12), key
        assert f["verdict"] in (MEETS, BELOW, NO_TARGET), key
        assert f"| {f['name']} |" in markdown, key
    for key in ("env_steps_per_s", "env_steps_per_cpu_s", "learner_updates_per_s",
                "learner_roofline_fp32", "learner_roofline_bf16", "sample_p99_minibatch_her",
                "replay_rss_growth"):
        assert figures[key]["target"] is not None, key
    no_scene = report["details"]["inserts_no_scene"]["episodes_per_s"]
    assert sorted(int(n) for n in no_scene) == list(plan.insert_no_scene_counts)
    machine = report["machine"]
    assert machine["cpu_count"] >= 1 and machine["versions"]["torch"]
    assert report["command"].startswith("python -m bench.perf.throughput --quick")
    assert report["git_commit"] and report["date"]
