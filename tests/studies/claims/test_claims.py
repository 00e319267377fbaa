"""studies/claims: per-run numbers (censoring, the cut at the epoch), grouping by config.yaml,
legacy against new-default runs, the not-enough-seeds rule, rliable's stand-ins, the CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from rliable import metrics

from hercs.apps.plots.curves import Curve
from hercs.apps.sweep import stats as sweep_stats
from hercs.run.rundir import RunDir
from studies.claims import claim_statistics
from tests.support import load_module

claim_runs = load_module("studies.claims.claim_runs")
claims = load_module("studies.claims.claims")
claims_report = load_module("studies.claims.claims_report")
REPO = Path(__file__).resolve().parents[3]
REPS = 200  # enough to exercise the bootstrap; the committed file uses claims.REPS
NEW_LAG = {"learner": {"prefetch_depth": 3}, "training": {"max_policy_lag": -1},
           "actor": {"insert_queue": 2}}


def _deep_merge(base: dict, extra: dict) -> dict:
    out = dict(base)
    for key, value in extra.items():
        out[key] = _deep_merge(out.get(key, {}), value) if isinstance(value, dict) else value
    return out


def _run(root: Path, name: str, method: str, seed: int, success: list[float],
         **config: dict) -> Path:
    run = root / name
    run.mkdir(parents=True)
    base = {"run": {"method": method, "seed": seed}, "task": {"name": "push"}}
    RunDir(run).config.write_text(yaml.safe_dump(_deep_merge(base, config)))
    rows = ["epoch,success_rate"] + [f"{e},{s}" for e, s in enumerate(success, start=1)]
    RunDir(run).metrics.write_text("\n".join(rows) + "\n")
    return run


def _ramp(start: int, n: int = 50) -> list[float]:
    """0 until epoch `start`, 1 from epoch start + 1 on."""
    return [0.0] * start + [1.0] * (n - start)


@pytest.fixture(autouse=True)
def _new_default_is_fixed(monkeypatch: pytest.MonkeyPatch) -> None:
    """The tests' "new default" is NEW_LAG whatever hercs.config's defaults become."""
    fixed = claim_runs.lag_setting(NEW_LAG)
    for module in (claim_runs, claims):  # where runs are labelled, and where claims choose
        monkeypatch.setattr(module, "new_default_lag", lambda: fixed)


# ---------------------------------------------------------------------------- per run

def _score(success: list[float], epoch: int = 50):
    curve = Curve("FetchPush", "her", 1, np.arange(1, len(success) + 1),
                  np.array(success, dtype=float))
    return claim_runs.score(claim_runs.Run("r", 1, len(success), curve), epoch)


def test_a_run_that_crosses_gets_the_tables_epoch_and_its_success_at_50() -> None:
    # trailing 10-epoch mean of a 0→1 step after epoch 30: 0.6 at epoch 36 (first > .5),
    # so the epoch at 0.5 is 35 counted from 0; after epoch 50 the mean is 1.
    s = _score(_ramp(30))
    assert (s.at_half, s.censored, s.success) == (35, False, pytest.approx(1.0))


def test_a_run_that_never_crosses_by_the_epoch_is_censored_at_the_epoch() -> None:
    s = _score([0.3] * 50)
    assert (s.at_half, s.censored, s.success) == (50, True, pytest.approx(0.3))
    # a tie at exactly 0.5 is not "exceeds": still censored
    assert _score([0.5] * 50).censored


def test_a_run_is_cut_at_the_epoch_and_one_shorter_is_left_out() -> None:
    late = _score(_ramp(60, 100))  # crosses at 65, after the cut
    assert (late.at_half, late.censored, late.success) == (50, True, 0.0)
    assert _score(_ramp(10, 49)) is None
    assert _score(_ramp(10, 40), epoch=40).at_half == 15


# ---------------------------------------------------------------------------- groups

def test_groups_follow_the_config_and_missing_keys_take_the_old_defaults(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    _run(runs, "legacy", "her-cs", 1, _ramp(30))
    _run(runs, "legacy-again", "her-cs", 2, _ramp(30), task={"env_version": "v4"})
    _run(runs, "v1", "her-cs", 1, _ramp(30), task={"env_version": "v1"})
    _run(runs, "new", "her-cs", 1, _ramp(30), **NEW_LAG)
    _run(runs, "other-lag", "her-cs", 1, _ramp(30),
         **_deep_merge(NEW_LAG, {"learner": {"prefetch_depth": 0}}))
    _run(runs, "lockstep", "her-cs", 1, _ramp(30), training={"schedule": "lockstep"})
    _run(runs, "lockstep-new", "her-cs", 2, _ramp(30),
         **_deep_merge(NEW_LAG, {"training": {"schedule": "lockstep"}}))
    _run(runs, "bf16", "her-cs", 1, _ramp(30), learner={"precision": "bf16"})
    (runs / "not-a-run").mkdir()
    groups = claim_runs.load_groups(runs)
    names = {g: [r.name for r in rs] for g, rs in groups.items() if g.schedule != "authors"}
    legacy = claim_runs.Group("FetchPush", "her-cs", lag=claim_runs.LEGACY)
    assert names == {
        legacy: ["legacy", "legacy-again"],
        claim_runs.Group("FetchPush", "her-cs", env="v1", lag=claim_runs.LEGACY): ["v1"],
        claim_runs.Group("FetchPush", "her-cs", lag=claim_runs.lag_setting(NEW_LAG)): ["new"],
        claim_runs.Group("FetchPush", "her-cs", lag="prefetch_depth=0, max_policy_lag=-1, "
                                                "insert_queue=2"): ["other-lag"],
        # lockstep has no policy lag: the lag settings do not split it
        claim_runs.Group("FetchPush", "her-cs", schedule="lockstep"): ["lockstep", "lockstep-new"],
        claim_runs.Group("FetchPush", "her-cs", precision="bf16", lag=claim_runs.LEGACY): ["bf16"],
    }
    assert legacy.label == "HER-CS, v4, async (legacy), fp32"
    assert claim_runs.Group("FetchPush", "her", lag=claim_runs.lag_setting(NEW_LAG)).label == (
        "HER, v4, async (new default), fp32")
    authors = groups[claim_runs.Group("FetchPush", "her-cs", env="v1", schedule="authors")]
    assert [r.seed for r in authors] == [121, 123, 125, 127, 133]


def test_a_run_with_another_weld_or_energy_floor_is_never_a_seed_of_the_plain_group(
        tmp_path: Path) -> None:
    # before the setting was part of the group, the ε run (its name sorts first) stood in
    # for the plain run of its seed, and the torquescale run could have
    _run(tmp_path, "push-eps1e-3-her-ebp-cs-s1", "her-ebp-cs", 1, _ramp(30, 50), **NEW_LAG,
         energy={"epsilon": 0.001})
    _run(tmp_path, "push-her-ebp-cs-s1", "her-ebp-cs", 1, _ramp(30, 50), **NEW_LAG)
    _run(tmp_path, "push-ts4-her-ebp-cs-s1", "her-ebp-cs", 1, _ramp(30, 60),
         **_deep_merge(NEW_LAG, {"task": {"weld_torquescale": 4.0}}))
    groups = claim_runs.load_groups(tmp_path)
    lag = claim_runs.lag_setting(NEW_LAG)
    names = {g: [r.name for r in rs] for g, rs in groups.items() if g.schedule != "authors"}
    assert names == {
        claim_runs.Group("FetchPush", "her-ebp-cs", lag=lag): ["push-her-ebp-cs-s1"],
        claim_runs.Group("FetchPush", "her-ebp-cs", lag=lag, setting="ε 0.001"): [
            "push-eps1e-3-her-ebp-cs-s1"],
        claim_runs.Group("FetchPush", "her-ebp-cs", lag=lag, setting="torquescale 4"): [
            "push-ts4-her-ebp-cs-s1"]}
    assert claim_runs.Group("FetchPush", "her-ebp-cs", lag=lag, setting="ε 0.001").label == (
        "HER-EBP-CS, v4, async (new default), fp32, ε 0.001")


def test_two_runs_of_one_group_and_seed_are_one_seed_the_longer(tmp_path: Path) -> None:
    _run(tmp_path / "a", "push-her-s1", "her", 1, _ramp(30, 20))
    _run(tmp_path / "a", "push-her-s1-again", "her", 1, _ramp(30, 50))
    groups = claim_runs.load_groups(tmp_path / "a")
    ours = [rs for g, rs in groups.items() if g.schedule != "authors"]
    assert [[(r.name, r.epochs) for r in rs] for rs in ours] == [[("push-her-s1-again", 50)]]


# -------------------------------------------------------------- claims and the seeds rule

CS_VS_HER = claims.Claim("HER-CS against HER", claims._push("her-cs"), claims._push("her"))


def _grid(root: Path, cs_seeds: int, her_seeds: int, tag: str = "", **config: dict) -> dict:
    """HER-CS seeds crossing at 20 + seed, HER seeds at 30 + seed (counted from 0: + 5)."""
    for seed in range(1, cs_seeds + 1):
        _run(root, f"cs-{seed}{tag}", "her-cs", seed, _ramp(20 + seed), **config)
    for seed in range(1, her_seeds + 1):
        _run(root, f"her-{seed}{tag}", "her", seed, _ramp(30 + seed), **config)
    return claim_runs.load_groups(root)


def test_a_side_with_one_seed_gets_no_numbers(tmp_path: Path) -> None:
    groups = _grid(tmp_path, 1, 3)
    [r] = claims.evaluate([CS_VS_HER], groups, reps=REPS)
    assert (r.x.n, r.y.n) == (1, 3)
    assert r.x_stats is None and r.improvement is None
    assert r.y_stats is not None  # a side with enough seeds keeps its own numbers
    text = claims_report.report([r], groups, "cmd", reps=REPS)
    row = next(line for line in text.splitlines() if line.startswith("| HER-CS against HER"))
    assert "not enough seeds (X n=1) | – | – | – | – | – |" in row


def test_a_side_whose_runs_stopped_early_says_so(tmp_path: Path) -> None:
    _run(tmp_path, "cs-1", "her-cs", 1, _ramp(10, 40))
    _run(tmp_path, "cs-2", "her-cs", 2, _ramp(10, 40))
    _run(tmp_path, "her-1", "her", 1, _ramp(30))
    _run(tmp_path, "her-2", "her", 2, _ramp(30))
    groups = claim_runs.load_groups(tmp_path)
    [r] = claims.evaluate([CS_VS_HER], groups, reps=REPS)
    assert (r.x.n, r.x.short) == (0, ["cs-1", "cs-2"])
    text = claims_report.report([r], groups, "cmd", reps=REPS)
    assert "not enough seeds (X n=0, 2 shorter than 50 epochs)" in text
    assert "| cs-1 | stopped before epoch 50: left out | – |" in text


def test_a_runs_hand_written_note_is_listed_with_it_on_one_line(tmp_path: Path) -> None:
    noted = _run(tmp_path, "cs-1", "her-cs", 1, _ramp(20))
    _run(tmp_path, "cs-2", "her-cs", 2, _ramp(25))
    (noted / claim_runs.NOTES_FILE).write_text("# cs-1\n\nits lag reads 60:\nit was resumed.\n")
    groups = claim_runs.load_groups(tmp_path)
    assert {r.name: r.note for rs in groups.values() for r in rs if r.name.startswith("cs")} == {
        "cs-1": "its lag reads 60: it was resumed.", "cs-2": ""}
    text = claims_report.report(claims.evaluate([CS_VS_HER], groups, reps=REPS), groups, "cmd",
                                reps=REPS)
    assert "**Notes on runs**\n\n- **cs-1**: its lag reads 60: it was resumed." in text
    assert "**cs-2**" not in text


def test_a_claim_with_its_own_epoch_cuts_both_sides_there(tmp_path: Path) -> None:
    """The bf16 runs are 40 epochs: their claim cuts both sides at 40, where a 50-epoch run
    that crosses at 45 is censored (at 40), and the runs' table says at which epoch."""
    _run(tmp_path, "cs-1", "her-cs", 1, _ramp(10, 40))
    _run(tmp_path, "cs-2", "her-cs", 2, _ramp(12, 40))
    _run(tmp_path, "her-1", "her", 1, _ramp(40))
    _run(tmp_path, "her-2", "her", 2, _ramp(20))
    groups = claim_runs.load_groups(tmp_path)
    at40 = replace(CS_VS_HER, title="HER-CS against HER, at epoch 40", epoch=40)
    [r] = claims.evaluate([at40], groups, reps=REPS)
    assert (r.x.n, r.y.n, r.x.epoch) == (2, 2, 40)
    assert [s.at_half for s in r.x.scores] == [15, 17]
    assert [(s.at_half, s.censored) for s in r.y.scores] == [(40, True), (25, False)]
    text = claims_report.report([r], groups, "cmd", reps=REPS)
    assert "| HER (at epoch 40) | her-1 | .00 | never (40, censored) |" in text.replace(
        ", v4, async (legacy), fp32", "")
    # the same runs at the report's epoch 50: the HER-CS side is too short
    [r50] = claims.evaluate([CS_VS_HER], groups, reps=REPS)
    assert (r50.x.n, r50.x.short) == (0, ["cs-1", "cs-2"])


def test_numbers_by_hand_for_two_against_two(tmp_path: Path) -> None:
    """HER-CS crosses at 25 and 26, HER at 35 and never (counted as 50): every HER-CS run
    is earlier, so P(earlier) = 1 in every resample. After epoch 50 HER-CS is at 1, 1 and HER
    at 1, .2: a tie and a win per HER-CS run, P(X > Y) = .75; HER's resamples {1, 1}, {1, .2},
    {.2, .2} give .5, .75, 1, the interval's ends."""
    _run(tmp_path, "cs-1", "her-cs", 1, _ramp(20))
    _run(tmp_path, "cs-2", "her-cs", 2, _ramp(21))
    _run(tmp_path, "her-1", "her", 1, _ramp(30))
    _run(tmp_path, "her-2", "her", 2, [0.2] * 50)
    groups = claim_runs.load_groups(tmp_path)
    [r] = claims.evaluate([CS_VS_HER], groups, reps=REPS)
    assert [s.at_half for s in r.x.scores] == [25, 26]
    assert [(s.at_half, s.censored) for s in r.y.scores] == [(35, False), (50, True)]
    assert r.y_stats.epoch_mean.value == pytest.approx(42.5)
    assert r.y_stats.epoch_iqm.value == pytest.approx(42.5)  # 2 runs: nothing trimmed
    assert (r.y_stats.epoch_mean.low, r.y_stats.epoch_mean.high) == (35.0, 50.0)
    assert r.y_stats.success_mean.value == pytest.approx(0.6)
    success, earlier = r.improvement
    assert (success.value, success.low, success.high) == (0.75, 0.5, 1.0)
    assert (earlier.value, earlier.low, earlier.high) == (1.0, 1.0, 1.0)
    # the 6 splits of the pooled runs: for the success, the 3 that give HER-CS the .2 read
    # P = .25 and the other 3 .75, so .75 is no tail (p = 1); for the epoch at 0.5 only the
    # observed split reads 1, the most 2 seeds a side can show (p = 2 · 1/6)
    assert r.exact_p is not None
    assert r.exact_p[:2] == (pytest.approx(1.0), pytest.approx(1 / 3))
    text = claims_report.report([r], groups, "cmd", reps=REPS)
    assert "| .75 [.50, 1.00] | 1.00 |" in text
    assert "| 1.00 [1.00, 1.00] | .333 |" in text
    assert "| 2 / 2 | 0 / 1 | 25.5 [25.0, 26.0] | 42.5 [35.0, 50.0] |" in text
    assert "never (50, censored)" in text


def test_the_new_default_is_taken_where_both_sides_have_two_seeds_else_legacy(
        tmp_path: Path) -> None:
    _grid(tmp_path, 3, 3)  # legacy
    groups = _grid(tmp_path, 2, 1, "-new", **NEW_LAG)  # new default: HER has one seed only
    x, y = claims.resolve(CS_VS_HER, groups)
    assert (x.group.lag, y.group.lag, x.n, y.n) == (claim_runs.LEGACY, claim_runs.LEGACY, 3, 3)
    _run(tmp_path, "her-2-new", "her", 2, _ramp(31), **NEW_LAG)
    x, y = claims.resolve(CS_VS_HER, claim_runs.load_groups(tmp_path))
    assert x.group.lag == y.group.lag == claim_runs.lag_setting(NEW_LAG)
    assert (x.n, y.n) == (2, 2)


def test_a_lockstep_side_is_not_split_by_lag_and_an_empty_claim_names_the_new_default(
        tmp_path: Path) -> None:
    _run(tmp_path, "lock-1", "her-cs", 1, _ramp(20), training={"schedule": "lockstep"})
    groups = claim_runs.load_groups(tmp_path)
    lockstep = claims.Claim("lockstep against asynchronous",
                            claims._push("her-cs", schedule="lockstep"), claims._push("her-cs"))
    x, y = claims.resolve(lockstep, groups)
    assert (x.group.lag, x.n) == ("", 1)
    assert (y.group.lag, y.n) == (claim_runs.lag_setting(NEW_LAG), 0)


def test_output_is_deterministic_and_leaves_numpys_global_rng_alone(tmp_path: Path) -> None:
    groups = _grid(tmp_path, 3, 2)
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    first = claims_report.report(claims.evaluate(claims.CLAIMS[:3], groups, reps=REPS), groups, "c")
    assert np.array_equal(np.random.get_state()[1], before)
    np.random.seed(7)  # the caller's RNG does not leak into the intervals
    assert claims_report.report(claims.evaluate(claims.CLAIMS[:3], groups, reps=REPS), groups,
                         "c") == first


# ----------------------------------------------------------- the stand-ins for rliable's

@pytest.mark.parametrize("x, y", [
    ([0.1, 0.5, 0.9], [0.2, 0.4]),
    ([0.5, 0.5, 0.2], [0.5, 0.1, 0.5, 0.9]),  # ties across the sides
    ([50.0, 50.0, 39.0], [50.0, 50.0]),  # censored runs tie
    ([0.3, 0.7], [0.3, 0.7]),  # identical sides: rliable's special case, 0.5
    ([1.0], [0.0, 2.0, 1.0, 1.0, 0.5]),
], ids=["distinct", "ties", "censored", "identical", "one-run"])
def test_probability_of_improvement_equals_rliables(x: list[float], y: list[float]) -> None:
    """The one implementation the sweep report and the claims' bootstraps share."""
    a, b = np.array(x)[:, None], np.array(y)[:, None]
    assert sweep_stats.probability_of_improvement(a, b) == pytest.approx(
        metrics.probability_of_improvement(a, b), abs=1e-12)
    assert sweep_stats.probability_of_improvement(b, a) == pytest.approx(
        metrics.probability_of_improvement(b, a), abs=1e-12)


@pytest.mark.parametrize("nx, ny", [(2, 2), (3, 3), (3, 5), (5, 5), (6, 6), (12, 12)])
def test_the_exact_p_is_the_mann_whitney_tests(nx: int, ny: int) -> None:
    """Without ties, `rank_test_p` is the exact two-sided Mann–Whitney U test (scipy's own,
    an independent computation); past EXACT_SPLITS (12 a side) its random splits land
    within their Monte Carlo error (±.02 at 10,000 draws) of it."""
    from scipy import stats

    rng = np.random.default_rng(nx * 100 + ny)
    for shift in (0.0, 0.5, 1.5):
        x, y = rng.normal(shift, 1, nx), rng.normal(0, 1, ny)
        want = stats.mannwhitneyu(x, y, alternative="two-sided", method="exact").pvalue
        got = claim_statistics.rank_test_p(list(x), list(y))
        exact = claim_statistics._splits(nx, ny) <= claim_statistics.EXACT_SPLITS
        assert got == pytest.approx(want, abs=1e-12 if exact else 0.02)


def test_the_exact_p_of_identical_sides_is_1_and_full_separation_is_its_floor() -> None:
    assert claim_statistics.rank_test_p([0.3, 0.3, 0.3], [0.3, 0.3, 0.3]) == pytest.approx(1.0)
    # fully separated, 3 against 3: 1 split of 20 a tail, twice for two sides
    assert claim_statistics.rank_test_p([4, 5, 6], [1, 2, 3]) == pytest.approx(0.1)
    assert claim_statistics.rank_test_p([1, 2, 3], [4, 5, 6]) == pytest.approx(0.1)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 8, 20])
def test_iqm_equals_rliables(n: int) -> None:
    x = np.random.default_rng(n).random((n, 1))
    assert sweep_stats.iqm(x) == pytest.approx(metrics.aggregate_iqm(x), abs=1e-12)


# ------------------------------------------------------------------------ command line

def test_command_writes_claims_md(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    _grid(runs, 2, 2)
    readme = tmp_path / "README.md"  # a copy: the command rewrites its Results tables
    readme.write_text((REPO / "README.md").read_text())
    done = subprocess.run([sys.executable, "-m", "studies.claims", "--runs",
                           str(runs), "--out", str(tmp_path / "out"), "--reps", "200",
                           "--readme", str(readme)],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert done.returncode == 0, done.stderr
    assert readme.read_text() != (REPO / "README.md").read_text()  # rewritten from these runs
    text = (tmp_path / "out" / "claims.md").read_text()
    assert text.startswith("# The claims, with intervals over seeds")
    assert f"--runs {runs} --out {tmp_path / 'out'} --reps 200 --readme {readme}`" in text
    assert "200 reps" in text
    assert "| HER-CS against HER, v4 | HER-CS, v4, async (legacy), fp32 |" in text
    bad = subprocess.run([sys.executable, "-m", "studies.claims", "--runs",
                          str(tmp_path / "nowhere")], capture_output=True, text=True, timeout=60,
                         cwd=REPO)
    assert bad.returncode == 2 and "not a directory" in bad.stderr
    few = subprocess.run([sys.executable, "-m", "studies.claims", "--reps", "10"],
                         capture_output=True, text=True, timeout=60, cwd=REPO)
    assert few.returncode == 2 and "--reps must be at least 100, got 10" in few.stderr


# ------------------------------------------------------------ the epoch at 0.9, provenance

def test_the_epoch_at_0_9_is_counted_like_the_one_at_0_5() -> None:
    # 0.95 from epoch 31 on: the trailing mean first exceeds .5 at epoch 36 and .9 at 40
    s = _score([0.0] * 30 + [0.95] * 20)
    assert (s.at_half, s.at_high, s.censored_high) == (35, 39, False)
    never = _score([0.0] * 30 + [0.85] * 20)
    assert (never.censored, never.at_high, never.censored_high) == (False, 50, True)


def test_the_epoch_at_0_9_table_has_numbers_by_hand(tmp_path: Path) -> None:
    """HER-CS reaches .9 at 25 and 26 (a 0→1 step), HER never by 50: P(earlier) = 1."""
    _run(tmp_path, "cs-1", "her-cs", 1, _ramp(15))
    _run(tmp_path, "cs-2", "her-cs", 2, _ramp(16))
    _run(tmp_path, "her-1", "her", 1, [0.8] * 50)
    _run(tmp_path, "her-2", "her", 2, [0.2] * 50)
    groups = claim_runs.load_groups(tmp_path)
    [r] = claims.evaluate([CS_VS_HER], groups, reps=REPS)
    assert [s.at_high for s in r.x.scores] == [24, 25]
    assert r.high.x_mean.value == pytest.approx(24.5)
    assert (r.high.y_iqm.value, r.high.y_iqm.low, r.high.y_iqm.high) == (50.0, 50.0, 50.0)
    assert (r.high.earlier.value, r.high.earlier.low, r.high.earlier.high) == (1.0, 1.0, 1.0)
    text = claims_report.report([r], groups, "cmd", reps=REPS)
    assert "| 2 / 2 | 0 / 2 | 24.5 [24.0, 25.0] | 50.0 [50.0, 50.0] |" in text
    # the 0.5 numbers are bootstrapped as before the 0.9 ones existed
    assert r.improvement == claim_statistics.improvement(r.x.scores, r.y.scores, REPS)


def test_each_sides_commits_days_machines_and_assumed_settings_are_listed(
        tmp_path: Path) -> None:
    made = {"commit": "abc1234", "finished": "2026-11-26T20:13:00+00:00",
            "machine": {"cpu": "AMD EPYC (family 25 model 17; avx2 avx512f)", "boot_id": "b1"}}
    for run in (_run(tmp_path, "cs-1", "her-cs", 1, _ramp(20)),
                _run(tmp_path, "her-1", "her", 1, _ramp(30))):
        (run / claim_runs.DONE_FILE).write_text(json.dumps(made))
    _run(tmp_path, "cs-2", "her-cs", 2, _ramp(21), training={"schedule": "async"})
    (tmp_path / "cs-2" / claim_runs.DONE_FILE).write_text(json.dumps(
        {"commit": "def5678 (with uncommitted changes)", "finished": "2026-11-27T01:00:00"}))
    _run(tmp_path, "her-2", "her", 2, [0.2] * 50, training={"schedule": "async"},
         learner={"precision": "fp32"})
    groups = claim_runs.load_groups(tmp_path)
    text = claims_report.report(claims.evaluate([CS_VS_HER], groups, reps=REPS), groups, "c",
                         reps=REPS)
    assert ("| HER-CS, v4, async (legacy), fp32 | 2 | abc1234, def5678+ | 2026-11-26 – "
            "2026-11-27 | AMD EPYC (avx512), boot b1, not recorded (1) | "
            "learner.precision=fp32 (2 runs), training.schedule=async (1 run) |") in text
    assert ("| HER, v4, async (legacy), fp32 | 2 | abc1234, not recorded (1) | 2026-11-26 | "
            "AMD EPYC (avx512), boot b1, not recorded (1) | learner.precision=fp32 (1 run), "
            "training.schedule=async (1 run) |") in text
    assert "*Settings assumed*: cs-1, cs-2, her-1 predate" in text
    assert "with 2 seeds a side the bootstrap" in text


def test_a_pooled_side_holds_each_run_of_its_parts_once(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    from studies.authors_peer import PEER_SCHEDULE

    _run(tmp_path, "ours-1", "her-cs", 1, _ramp(20), **NEW_LAG)
    _run(tmp_path, "ours-2", "her-cs", 2, _ramp(22), **NEW_LAG)
    _run(tmp_path, "legacy-3", "her-cs", 3, _ramp(24))  # another lag setting: not a part
    _run(tmp_path, "peer-121", "her-cs", 121, _ramp(26),
         training={"schedule": PEER_SCHEDULE})
    pool = claims._push("her-cs", schedule=claim_runs.POOLED, lag="", setting="ours and theirs")
    # an asynchronous part takes the new default's lag setting, as the claims' sides do
    monkeypatch.setattr(claims, "POOLS", {pool: (
        claims._push("her-cs", lag=""), claims._push("her-cs", schedule=PEER_SCHEDULE, lag=""))})
    groups = claim_runs.load_groups(tmp_path)
    published = claims._push("her-cs", env="v1", schedule="authors", lag="")
    [r] = claims.evaluate([claims.Claim("pooled against the published", pool, published)],
                          groups, reps=REPS)
    assert sorted(s.run for s in r.x.scores) == ["ours-1", "ours-2", "peer-121"]
    assert r.x_stats is not None and r.exact_p is not None
    assert pool.label == "HER-CS, v4: ours and theirs"
    assert pool not in groups  # the caller's groups are left as they were
    # a part named twice, and the published curves, whose runs share names across methods
    both_published = claims._push("her", env="v1", schedule="authors", lag="")
    monkeypatch.setattr(claims, "POOLS", {pool: (published, published, both_published)})
    [twice] = claims.evaluate([claims.Claim("twice", pool, published)], groups, reps=REPS)
    assert twice.x.n == 10  # five HER-CS and five HER seeds, each once
    # a pool a part of which has no runs is no side at all, not the other parts alone
    monkeypatch.setattr(claims, "POOLS", {pool: (claims._push("her-cs", lag=""),
                                                 claims._push("her-ebp", lag=""))})
    [partial] = claims.evaluate([claims.Claim("partial", pool, published)], groups, reps=REPS)
    assert partial.x.n == 0 and partial.x_stats is None


# ------------------------------------------------- verdicts, epochs chosen late, start commits

def _p(value: float, low: float, high: float) -> claim_statistics.Estimate:
    return claim_statistics.Estimate(value, low, high)


@pytest.mark.parametrize(("nx", "ny", "p", "word"), [
    (3, 5, _p(0.47, 0.0, 1.0), "lead (fewer than 5 runs a side)"),  # ours against their code
    (2, 5, _p(0.0, 0.0, 0.0), "lead (fewer than 5 runs a side)"),  # TF32: every run below
    (8, 4, _p(0.1, 0.0, 0.3), "lead (fewer than 5 runs a side)"),
    (5, 5, _p(0.64, 0.24, 1.0), "lead (interval holds .5)"),
    (5, 5, _p(0.7, 0.5, 0.9), "lead (interval holds .5)"),  # an end at .5 holds it
    (5, 5, _p(0.12, 0.0, 0.4), "Y ahead in these seeds"),  # ours against the published
    (6, 5, _p(0.96, 0.76, 1.0), "X ahead in these seeds"),
], ids=["3-against-5", "2-against-5-separated", "4-on-one-side", "holds-half",
        "ends-at-half", "y-ahead", "x-ahead"])
def test_a_verdict_is_a_lead_below_5_runs_a_side_or_where_the_interval_holds_half(
        nx: int, ny: int, p: claim_statistics.Estimate, word: str) -> None:
    assert claims.verdict(nx, ny, p) == word


def test_every_table_row_carries_its_verdict(tmp_path: Path) -> None:
    groups = _grid(tmp_path, 2, 2)
    text = claims_report.report(claims.evaluate([CS_VS_HER], groups, reps=REPS), groups, "cmd",
                                reps=REPS)
    rows = [line for line in text.splitlines() if line.startswith("| HER-CS against HER |")]
    assert len(rows) == 3  # success, epoch at 0.5, epoch at 0.9
    assert all(row.endswith("| lead (fewer than 5 runs a side) |") for row in rows)


def test_an_epoch_chosen_after_seeing_the_data_is_labelled_on_every_line_that_reads_it(
        tmp_path: Path) -> None:
    groups = _grid(tmp_path, 2, 2)
    late = replace(CS_VS_HER, title="HER-CS against HER, at epoch 50", post_hoc=True)
    text = claims_report.report(claims.evaluate([late, CS_VS_HER], groups, reps=REPS), groups,
                                "cmd", reps=REPS)
    label = claims_report.POST_HOC_LABEL
    assert text.count(f"| HER-CS against HER, at epoch 50 {label} |") == 3
    assert text.count(f"| HER-CS against HER {label}") == 0
    # every claim of the committed file read at an epoch chosen late says so, and why
    late_claims = [c for c in claims.CLAIMS if c.post_hoc]
    assert {c.epoch for c in late_claims} == set(claims.POST_HOC_EPOCHS)
    assert all(c.epoch not in claims.POST_HOC_EPOCHS for c in claims.CLAIMS if not c.post_hoc)
    assert all(why in text for why in claims.POST_HOC_EPOCHS.values())


@pytest.mark.parametrize(("done", "peer", "commit"), [
    ({"commit": "aaa1111"}, None, "aaa1111"),
    ({"commit": "aaa1111", "resumed": False}, None, "aaa1111"),
    ({"commit": "aaa1111", "resumed": True}, None, "unknown→aaa1111"),
    ({"commit": "aaa1111", "resumed": True, "started_commit": ""}, None, "unknown→aaa1111"),
    ({"commit": "aaa1111", "resumed": True, "started_commit": "bbb2222"}, None,
     "bbb2222→aaa1111"),
    ({"commit": "aaa1111", "resumed": True, "started_commit": "aaa1111"}, None, "aaa1111"),
    ({"commit": "9f420bc"}, "cba30a9", "cba30a9→9f420bc"),  # the authors' code's seed 123
    ({"commit": "84889b4"}, "84889b4", "84889b4"),
    (None, None, ""),
], ids=["fresh", "not-resumed", "resumed-unrecorded", "resumed-blank", "resumed-recorded",
        "resumed-same-commit", "peer-config", "peer-same", "no-record"])
def test_the_start_commit_comes_from_bench_done_or_the_peer_config_and_is_never_invented(
        tmp_path: Path, done: dict | None, peer: str | None, commit: str) -> None:
    if done is not None:
        (tmp_path / claim_runs.DONE_FILE).write_text(json.dumps(done))
    config = {"peer": {"commit": "9c1bfa0", "started_commit": peer}} if peer else {}
    assert claim_runs.provenance(tmp_path, config)["commit"] == commit
