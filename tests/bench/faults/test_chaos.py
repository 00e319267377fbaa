"""bench/chaos*.py without a network: the schedule is what its seed and spans say, the
envelope check is calibrated on the fault-free seeds, a soak's state survives a round trip,
and a soak that broke a promise fails its report. The soak itself is
tests/fault/test_chaos_soak.py."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bench.faults import chaos_report
from bench.faults.chaos_envelope import (
    check,
    config_differences,
    leave_one_out,
    smoothed,
    success_curve,
)
from bench.faults.chaos_plan import QUICK_PLAN, ChaosPlan, Event, draw_events
from bench.faults.chaos_state import QUICK_SHAPE, SoakState, new_state
from hercs.run.rundir import RunDir

ACTORS = ["net-1", "net-2"]


def test_the_schedule_keeps_its_spans_and_one_cut_at_a_time() -> None:
    plan = ChaosPlan(horizon_s=4 * 3600.0)
    events = draw_events(plan, actors=ACTORS, rng=np.random.default_rng(7))
    kills = [e for e in events if e.kind == "kill"]
    cuts = [e for e in events if e.kind == "cut"]
    assert [e.at_s for e in events] == sorted(e.at_s for e in events)
    gaps = np.diff([0.0] + [e.at_s for e in kills])
    assert gaps.min() >= 60.0 - 0.1 and gaps.max() <= 120.0 + 0.1
    # 4 h / 90 s on average: about 160 kills, each target drawn about a fifth of the time
    assert 140 <= len(kills) <= 180
    shares = {t: sum(e.target == t for e in kills) / len(kills)
              for t in ("replay-0", "learner-0", "clusterer-0", "evaluator-0")}
    actor_share = sum(e.target in ACTORS for e in kills) / len(kills)
    assert all(0.1 < s < 0.3 for s in [*shares.values(), actor_share]), (shares, actor_share)
    assert all(30.0 <= c.duration_s <= 90.0 and c.target in ACTORS for c in cuts)
    for a, b in itertools.pairwise(cuts):  # the next cut starts 120-240 s after the heal
        assert 120.0 - 0.2 <= b.at_s - (a.at_s + a.duration_s) <= 240.0 + 0.2


def test_one_seed_draws_one_schedule() -> None:
    def draw(seed: int) -> list[Event]:
        return draw_events(ChaosPlan(), actors=ACTORS, rng=np.random.default_rng(seed))

    assert draw(3) == draw(3) and draw(3) != draw(4)


def test_the_quick_plan_is_one_actor_kill_then_one_cut() -> None:
    events = draw_events(QUICK_PLAN, actors=ACTORS, rng=np.random.default_rng(1))
    assert [(e.kind, e.target in ACTORS) for e in events] == [("kill", True), ("cut", True)]
    assert events[1].duration_s == 12.0
    assert [e.after_epoch for e in events] == [1, 2], "held until epochs 1 and 2"
    assert all(e.after_epoch == 0 for e in draw_events(ChaosPlan(max_kills=3, max_cuts=3),
                                                       actors=ACTORS,
                                                       rng=np.random.default_rng(1)))


@pytest.mark.parametrize("changes", [
    {"kill_gap_s": (120.0, 60.0)}, {"cut_s": (0.0, 5.0)}, {"targets": ("replay", "router")},
    {"targets": ()}, {"max_kills": -1},
], ids=["reversed-span", "zero-cut", "unknown-target", "no-target", "negative-count"])
def test_a_bad_plan_names_the_field(changes: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match=next(iter(changes))):
        ChaosPlan(**changes)


def test_smoothing_is_a_trailing_mean() -> None:
    assert smoothed([0.0, 0.3, 0.6, 0.9], 3) == pytest.approx([0.0, 0.15, 0.3, 0.6])
    assert math.isnan(smoothed([0.1, math.nan, 0.5], 2)[2])


def test_the_envelope_check_names_the_epochs_outside() -> None:
    seeds = [[0.0, 0.1, 0.2, 0.3], [0.1, 0.2, 0.4, 0.5]]
    inside = check([0.05, 0.15, 0.3, 0.4], seeds, window=1)
    assert inside.inside and inside.epochs == 4
    low = check([0.05, 0.15, 0.1, 0.4], seeds, window=1)
    assert not low.inside and low.outside == [(3, 0.1, 0.2, 0.4)]
    assert "outside at 1 of 4 epochs (3: 0.10 ∉ [0.20, 0.40])" in low.describe()
    # a one-epoch dip the trailing mean absorbs
    assert check([0.05, 0.15, 0.1, 0.4], seeds, window=3).inside
    # epochs beyond a seed's end are not compared
    assert check([0.05, 0.15, 0.3, 0.4, 0.9], seeds, window=1).epochs == 4


def test_each_fault_free_seed_is_checked_against_the_others() -> None:
    seeds = {"s1": [0.1, 0.2, 0.3], "s2": [0.2, 0.3, 0.4], "s3": [0.15, 0.25, 0.5]}
    calibration = leave_one_out(seeds, window=1)
    assert calibration["s1"].outside == [(1, 0.1, 0.15, 0.2), (2, 0.2, 0.25, 0.3),
                                         (3, 0.3, 0.4, 0.5)]
    assert calibration["s3"].outside == [(3, 0.5, 0.3, 0.4)]
    assert leave_one_out({"s1": [0.1], "s2": [0.2]}, window=1) == {}


def write_run(folder: Path, rates: list[float], **config: Any) -> Path:
    folder.mkdir(parents=True)
    rows = ["epoch,success_rate"] + [f"{e},{r}" for e, r in enumerate(rates, start=1)]
    RunDir(folder).metrics.write_text("\n".join(rows) + "\n")
    tree: dict[str, dict[str, Any]] = {
        "run": {"name": folder.name, "seed": 1}, "task": {"name": "push"},
        "training": {"epochs": 20, "cycles_per_epoch": 50}, "launch": {"max_restarts": 5}}
    for key, value in config.items():
        section, name = key.split("__")
        tree[section][name] = value
    RunDir(folder).config.write_text(yaml.safe_dump(tree))
    return folder


def test_a_curve_and_the_configuration_are_read_from_a_run_folder(tmp_path: Path) -> None:
    a = write_run(tmp_path / "chaos1-push-x-s1", [0.0, 0.05, 0.1])
    b = write_run(tmp_path / "nofault-push-x-s2", [0.0, 0.1], run__seed=2, training__epochs=40,
                  launch__max_restarts=1000)
    c = write_run(tmp_path / "nofault-push-x-s3", [0.0], training__cycles_per_epoch=10)
    assert success_curve(a) == [0.0, 0.05, 0.1]
    assert config_differences(a, b) == []  # seeds, lengths and supervision are not learning
    assert config_differences(a, c) == ["training.cycles_per_epoch: 50 ≠ 10"]


def test_only_run_folders_are_runs_not_the_logs_beside_them(tmp_path: Path) -> None:
    """The soak leaves `<run>.out` and each actor's `<run>.net-N.I.log` beside the run folder;
    they match the run's name pattern and once made the report compare configurations with a
    log file."""
    run = write_run(tmp_path / "nofault-push-x-s1", [0.0, 0.1])
    (tmp_path / "nofault-push-x-s1.out").write_text("hercs up: …\n")
    (tmp_path / "nofault-push-x-s1.net-1.0.log").write_text("actor: …\n")
    assert chaos_report._folders([tmp_path], "nofault-push-x*") == {run.name: run}


def soak_state(**changes: Any) -> SoakState:
    state = new_state(QUICK_SHAPE, chaos_seed=1, plan=QUICK_PLAN, quick=True)
    for key, value in changes.items():
        setattr(state, key, value)
    return state


def test_a_soak_state_survives_a_round_trip(tmp_path: Path) -> None:
    state = soak_state(next_event=1, elapsed_s=42.5, progress=[(1.5, "epoch 1/5  success 0.1")],
                       injections=[{"at_s": 14.0, "kind": "kill", "target": "net-2"}])
    state.save(tmp_path / "state.json")
    assert SoakState.load(tmp_path / "state.json") == state
    assert state.name == "chaos1-reach-her-cs-s1"
    assert new_state(QUICK_SHAPE, chaos_seed=None, plan=None,
                           quick=True).events == []


def record(name: str, *, rates: list[float], chaos_seed: int | None = 1,
           **result: Any) -> dict[str, Any]:
    row: dict[str, Any] = dict(
        setting=name, injected="kills: 3 (0 skipped), cuts: 1", exit_status=0,
        actor_exits=[0, 0], epochs_expected=len(rates),
        epochs_recorded=list(range(1, len(rates) + 1)), episodes=100, acked=90, lost=0,
        stored_records=90, stored_distinct=90, duplicate_acks=1, retries=5, superseded=2,
        unacked=0, lag_p50=2.0, lag_p95=3.0, inserts_per_s=1.5, longest_insert_gap_s=40.0,
        median_epoch_s=8.0, max_epoch_s=30.0, wall_s=600.0, load_before=4.0, load_after=6.0,
        first_insert_after_heal_s=None, next_epoch_after_heal_s=None, notes=[])
    row.update(result)
    row["stored_twice"] = row["stored_records"] - row["stored_distinct"]
    ok = row["lost"] == 0 and row["stored_twice"] == 0
    return {"name": name, "chaos_seed": chaos_seed, "quick": False, "plan": {
        "kill_gap_s": [60, 120], "cut_gap_s": [120, 240], "cut_s": [30, 90],
        "targets": ["replay", "actor"], "horizon_s": 21600}, "schedule": [],
        "schedule_drawn": 5, "injections": [
            {"at_s": 70.0, "planned_at_s": 69.5, "kind": "kill", "target": "replay-0",
             "pid": 123, "outcome": "done", "back_s": 1.1, "next_insert_s": 2.0,
             "next_epoch_s": 9.0},
            {"at_s": 150.0, "planned_at_s": 150.0, "kind": "cut", "target": "net-1",
             "duration_s": 45.0, "healed_at_s": 195.0, "pid": None, "outcome": "done",
             "back_s": 3.0, "next_insert_s": 4.0, "next_epoch_s": 12.0}],
            "up_exits": [0], "result": row, "success": rates, "ok": ok}


SEEDS = {"nofault-s1": [0.0, 0.1, 0.2, 0.3], "nofault-s2": [0.1, 0.2, 0.3, 0.4],
         "nofault-s3": [0.0, 0.2, 0.4, 0.5]}


@pytest.mark.parametrize(("changes", "ok"), [
    ({}, True), ({"lost": 1}, False), ({"stored_records": 91}, False),
    ({"rates": [0.9, 0.9, 0.9, 0.9]}, False),
], ids=["clean", "lost", "stored-twice", "outside-the-envelope"])
def test_the_report_fails_a_soak_that_broke_a_promise(changes: dict[str, Any],
                                                      ok: bool) -> None:
    rates = changes.pop("rates", [0.05, 0.15, 0.3, 0.4])
    text, verdict = chaos_report.report(
        [record("chaos1-push-x-s1", rates=rates, **changes)], SEEDS, [],
        command="python -m bench.faults.chaos", window=1, config_notes=[], full_commands=["cmd"])
    assert verdict is ok
    assert "| 70 s (69.5) | SIGKILL replay-0 | 123 | 1.1 s | 2 s | 9 s | done |" in text
    assert "| 150 s (150) | cut net-1 both ways 45 s (healed at 195 s) |" in text
    assert "## Full soak: not yet run" not in text and "QUICK MODE" not in text
    assert f"| 1 | {rates[0]:.2f} ({rates[0]:.2f}) | 0.00–0.10 | 0.00 | 0.10 | 0.00 |" in text


def test_a_soak_outside_no_more_often_than_a_fault_free_seed_passes() -> None:
    """A fault-free seed (nofault-s1) leaves the others' envelope at 3 of 4 epochs: a soak
    outside at 1 is no evidence of harm, one outside at all 4 is."""
    near = [0.05, 0.15, 0.2, 0.55]
    far = [0.3, 0.4, 0.6, 0.7]
    _, near_ok = chaos_report.report([record("chaos1", rates=near)], SEEDS, [], command="c",
                                     window=1, config_notes=[], full_commands=[])
    _, far_ok = chaos_report.report([record("chaos1", rates=far)], SEEDS, [], command="c",
                                    window=1, config_notes=[], full_commands=[])
    assert (near_ok, far_ok) == (True, False)


def test_the_report_says_when_the_fault_free_seeds_never_took_off() -> None:
    """Before the take-off every curve is noise near 0: the envelope then cannot judge
    learning, and the report says so; once a seed passes 0.5 it does not."""
    early = {"nofault-s1": [0.0, 0.1, 0.05], "nofault-s2": [0.05, 0.0, 0.1]}
    text, _ = chaos_report.report([record("chaos1", rates=[0.05, 0.05, 0.1])], early, [],
                                  command="c", window=1, config_notes=[], full_commands=[])
    assert "no fault-free seed got past a smoothed success of 0.10 (< 0.5)" in text
    text, _ = chaos_report.report([record("chaos1", rates=[0.05, 0.15, 0.3, 0.4])], SEEDS, [],
                                  command="c", window=1, config_notes=[], full_commands=[])
    assert "cannot tell a soak that goes on to learn" not in text


def test_a_quick_report_says_so_and_gives_the_soak_s_commands() -> None:
    quick = record("chaos1-reach-her-cs-s1", rates=[0.5, 0.9])
    quick["quick"] = True
    text, verdict = chaos_report.report([quick], {}, [],
                                        command="python -m bench.faults.chaos --quick",
                                        window=3, config_notes=[],
                                        full_commands=["python -m bench.faults.chaos"])
    assert verdict
    assert "QUICK MODE" in text and "not checked: no fault-free seeds" in text
    assert text.rstrip().endswith("```\npython -m bench.faults.chaos\n```")
    assert "## Full soak: not yet run" in text


def test_env_steps_per_update_are_read_per_epoch_and_an_excess_is_marked(
        tmp_path: Path) -> None:
    """chaos2's epoch 4 before the limiter followed the learner: 27,000 env steps for 2,000
    updates, 2.7 times a fault-free epoch's."""
    def run(name: str, steps: list[int]) -> Path:
        folder = tmp_path / name
        folder.mkdir()
        rows = ["epoch,env_steps,updates"] + [
            f"{e},{s},{2000 * e}" for e, s in enumerate(itertools.accumulate(steps), start=1)]
        RunDir(folder).metrics.write_text("\n".join(rows) + "\n")
        return folder

    free = run("nofault", [10200, 10000, 10000, 10000])
    bad = run("chaos2", [10200, 10000, 27000, 10400])
    assert chaos_report.steps_per_update(bad) == pytest.approx([5.1, 5.0, 13.5, 5.2])
    assert chaos_report.steps_per_update(tmp_path / "none") == []
    lines = chaos_report._steps_section({"chaos2": chaos_report.steps_per_update(bad)},
                                        {"nofault": chaos_report.steps_per_update(free)})
    row = next(line for line in lines if line.startswith("| chaos2 "))
    assert "+170.0% at epoch 3 ✗" in row
    assert "| nofault | none |" in "\n".join(lines)
