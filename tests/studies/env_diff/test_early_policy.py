"""studies/env_diff/early_policy.py: the facts of an episode are what its observations say, the
logged episodes are counted per epoch block, the committed moved shares are read per run, open-loop
replay is deterministic in a real FetchPush, and the committed report's findings hold in its own
data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.run.rundir import RunDir
from hercs.run.runlog import EpisodeLogWriter
from hercs.wire.codec import episode_to_msg
from hercs.wire.episode import EpisodeData
from studies.env_diff.early_policy import (
    EpisodeFacts,
    committed_moved_shares,
    energy_view,
    episode_blocks,
    episode_facts,
    replay_open_loop,
    run_environment,
)
from tests.support import REPO, saved_run_config

REPORT = REPO / "docs" / "results" / "early_policy.json"


def fetch_obs(grip: np.ndarray, cube: np.ndarray) -> np.ndarray:
    """(T+1, 25) observations with the gripper at 0:3 and the cube at 3:6."""
    obs = np.zeros((len(grip), 25), np.float32)
    obs[:, 0:3], obs[:, 3:6] = grip, cube
    return obs


def test_an_episodes_facts_are_what_its_observations_say() -> None:
    grip = np.array([[0, 0, 0], [0.3, 0, 0], [0.3, 0.4, 0], [0.3, 0.4, 0.3]], float)
    cube = np.array([[1, 1, 0]] * 3 + [[1, 1.004, 0]], float)
    f = episode_facts(fetch_obs(grip, cube))
    assert not f.moved  # 4 mm is under the replay's 5 mm
    assert f.path_m == pytest.approx(1.0, abs=1e-6)
    assert f.travel_m == pytest.approx(np.sqrt(0.09 + 0.16 + 0.09), abs=1e-6)
    assert f.height_m == pytest.approx(0.075, abs=1e-6)
    assert f.end_to_cube_m == pytest.approx(np.hypot(0.7, 0.6), abs=1e-6)
    cube[-1] = [1, 1.006, 0]
    assert episode_facts(fetch_obs(grip, cube)).moved


def test_logged_episodes_are_counted_per_epoch_block(tmp_path: Path) -> None:
    config = saved_run_config(tmp_path, ["task.name=push", "run.name=t",
                                         "training.cycles_per_epoch=1",
                                         "training.episodes_per_cycle=4"])
    spec = config.task.spec
    steps = spec.episode_steps
    with EpisodeLogWriter(RunDir(tmp_path).episode_log, run="t", task="push") as writer:
        for i in range(10):  # blocks of 4 ids: 0-3, 4-7, 8-9
            cube = np.zeros((steps + 1, 3))
            if i in (1, 4, 5, 6):  # the cube is pushed 1 cm in these
                cube[-1, 0] = 0.01
            ep = EpisodeData(obs=fetch_obs(np.zeros((steps + 1, 3)), cube),
                             ag=cube.astype(np.float32),
                             g=np.zeros((steps, 3), np.float32),
                             actions=np.full((steps, 4), float(i), np.float32),
                             actor_id="a", seq=i)
            writer.append_episode(episode_to_msg(ep, run="t", task="push"), episode_id=i)
    blocks, actions = episode_blocks(tmp_path, blocks=3)
    assert {b: f["episodes"] for b, f in blocks.items()} == {0: 4, 1: 4, 2: 2}
    assert {b: f["moved_share"] for b, f in blocks.items()} == {0: 0.25, 1: 0.75, 2: 0.0}
    assert actions == []
    # the open loop's actions come from the same pass, past the last block too
    blocks, actions = episode_blocks(tmp_path, blocks=1, actions_of=range(6, 9))
    assert blocks.keys() == {0} and [a[0, 0] for a in actions] == [6.0, 7.0, 8.0]


def write_run(folder: Path, name: str, overrides: list[str], shares: list[str] | None,
              sampled: list[str] | None = None) -> None:
    run = folder / name
    run.mkdir()
    save_yaml(apply_overrides(HercsConfig(), overrides), RunDir(run).config)
    header = ("epoch,success_rate" + (",buffer_moved_share" if shares is not None else "")
              + (",sampled_moved_share" if sampled is not None else ""))
    rows = [f"{e + 1},0.0" + (f",{s}" if shares is not None else "")
            + (f",{sampled[e]}" if sampled is not None else "")
            for e, s in enumerate(shares or ["x"] * 3)]
    RunDir(run).metrics.write_text("\n".join([header, *rows]) + "\n")


def test_energy_view_splits_a_blocks_draws_between_still_and_moved_episodes() -> None:
    def facts(moved: bool) -> EpisodeFacts:
        return EpisodeFacts(moved=moved, path_m=0.0, travel_m=0.0, height_m=0.0,
                            end_to_cube_m=0.0)

    block = [facts(False), facts(False), facts(True)]
    view = energy_view(block, [1e-3, 3e-3, 0.2], epsilon=1e-6)
    assert view["still_energy"] == 2e-3 and view["moved_energy"] == 0.2
    # p ∝ e + ε: the two still episodes hold (4e-3 + 2e-6) of (0.204 + 3e-6)
    assert abs(view["still_draw_share"] - (4e-3 + 2e-6) / (0.204 + 3e-6)) < 1e-5
    # a larger ε lifts the still episodes' share even where their energy is nil
    assert energy_view(block, [0.0, 0.0, 0.2], epsilon=1e-3)["still_draw_share"] > 0.009
    assert energy_view([facts(True)], [0.1])["still_energy"] == 0.0


def test_committed_moved_shares_are_read_per_push_run(tmp_path: Path) -> None:
    write_run(tmp_path, "push-v1-her-s1", ["task.name=push", "task.env_version=v1",
                                           "run.method=her"], ["0.1", "0.2", "0.3"])
    write_run(tmp_path, "push-ts4-her-s1", ["task.name=push", "task.weld_torquescale=4",
                                            "run.method=her"], ["0.1", "0.05", "0.04"])
    write_run(tmp_path, "push-old-s1", ["task.name=push"], None)  # before the column existed
    write_run(tmp_path, "pick-her-s1", ["task.name=pick"], ["0.5", "0.5", "0.5"])
    write_run(tmp_path, "push-eps-s1", ["task.name=push", "run.method=her-ebp-cs",
                                        "energy.epsilon=0.001"], ["0.1", "0.1", "0.2"],
              sampled=["0.9", "0.95", "1.0"])
    rows = committed_moved_shares(tmp_path, epochs=(1, 3, 5))
    assert rows == [
        {"run": "push-eps-s1", "env": "v4", "method": "her-ebp-cs, ε 0.001",
         "share": {"1": 0.1, "3": 0.2}, "sampled_early": 0.95},
        {"run": "push-ts4-her-s1", "env": "v4 torquescale 4", "method": "her",
         "share": {"1": 0.1, "3": 0.04}, "sampled_early": None},
        {"run": "push-v1-her-s1", "env": "v1", "method": "her",
         "share": {"1": 0.1, "3": 0.3}, "sampled_early": None}]
    assert run_environment({}) == "v4"


def test_open_loop_replay_in_a_real_fetchpush_is_deterministic() -> None:
    from hercs.rl.envs import make_env
    from hercs.rl.task_registry import task_spec

    env = make_env(task_spec("push", "v4"))
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, (50, 4)) for _ in range(2)]
    first = replay_open_loop(env, actions)
    assert replay_open_loop(env, actions) == first
    assert first["episodes"] == 2 and first["path_m"] > 0.1
    still = replay_open_loop(env, [np.zeros((50, 4))])
    assert still["moved_share"] == 0.0 and still["path_m"] < 0.01


@pytest.mark.skipif(not REPORT.exists(), reason="docs/results/early_policy.json not committed")
@pytest.mark.docs_check
def test_docs_check_the_committed_findings_hold_in_the_committed_data() -> None:
    """Not a test of the code: a consistency check of docs/results/early_policy.md's findings
    against the data committed beside them (early_policy.json)."""
    result = json.loads(REPORT.read_text())

    def late(run: dict, key: str) -> float:
        return float(np.mean([b[key] for k, b in run["blocks"].items() if 3 <= int(k) <= 11]))

    runs = result["episodes"]

    def group(env: str, *methods: str) -> list[dict]:
        return [r for r in runs.values() if r["env"] == env and r.get("method") in methods]

    v1, v4 = group("v1", "her-ebp-cs"), group("v4", "her-ebp-cs")
    assert len(v1) >= 5 and len(v4) >= 5
    # HER-EBP-CS: every v1 run's early policy moves the cube more often and ends nearer it
    # than any v4 run's
    assert min(late(r, "moved_share") for r in v1) > max(late(r, "moved_share") for r in v4)
    assert max(late(r, "end_to_cube_m") for r in v1) < min(late(r, "end_to_cube_m") for r in v4)
    assert max(late(r, "path_m") for r in v1) < min(late(r, "path_m") for r in v4)
    assert min(late(r, "height_m") for r in v4) > max(late(r, "height_m") for r in v1)
    # HER and HER-CS do not wander on v4: their v4 runs end as near the cube as the v1 runs
    # of any method, and move it as often as v1's HER-EBP-CS
    plain_v1, plain_v4 = group("v1", "her", "her-cs"), group("v4", "her", "her-cs")
    assert len(plain_v1) >= 6 and len(plain_v4) >= 4
    v1_ends = [late(r, "end_to_cube_m") for r in v1 + plain_v1]
    assert max(late(r, "end_to_cube_m") for r in plain_v4) < min(
        late(r, "end_to_cube_m") for r in v4)
    assert max(late(r, "end_to_cube_m") for r in plain_v4) <= max(v1_ends) + 0.01
    assert min(late(r, "moved_share") for r in plain_v4) > max(late(r, "moved_share") for r in v4)
    # EBP's energy: the still episodes' mean energy in blocks 0-5 is >= 10x higher on v1 in
    # every HER-EBP-CS run, and their share of p ∝ energy + ε draws >= 4x
    def early(run: dict, key: str) -> float:
        return float(np.mean([b[key] for k, b in run["blocks"].items() if int(k) <= 5]))

    assert min(early(r, "still_energy") for r in v1) > 10 * max(
        early(r, "still_energy") for r in v4)
    assert min(early(r, "still_draw_share") for r in v1) > 4 * max(
        early(r, "still_draw_share") for r in v4)
    # ε 1e-3 on v4 (v1's floor): every such run's early policy is outside every plain v4
    # run's range on each fact, towards v1's, and its still episodes get v1's share of draws
    screened = [r for r in runs.values() if r["env"] == "v4" and "ε 0.001" in r["method"]]
    for run in screened:
        for key in ("end_to_cube_m", "travel_m", "height_m"):
            assert late(run, key) < min(late(r, key) for r in v4), key
        assert late(run, "moved_share") > max(late(r, "moved_share") for r in v4)
        assert early(run, "still_draw_share") > 4 * max(early(r, "still_draw_share")
                                                         for r in v4)
    # the same actions without feedback: the cube moves in as many episodes, the gripper's
    # path is 0-6 % longer on v4 and its net travel 0-12 %, a tenth of the closed-loop gap
    loop = result["open_loop"]
    assert len(loop) >= 6
    for name, per_env in loop.items():
        assert abs(per_env["v4"]["moved_share"] - per_env["v1"]["moved_share"]) <= 0.02, name
        assert 1.0 <= per_env["v4"]["path_m"] / per_env["v1"]["path_m"] <= 1.06, name
        assert 1.0 <= per_env["v4"]["travel_m"] / per_env["v1"]["travel_m"] <= 1.12, name
    closed = np.mean([late(r, "travel_m") for r in v4]) / np.mean(
        [late(r, "travel_m") for r in v1])
    opened = max(per_env["v4"]["travel_m"] / per_env["v1"]["travel_m"] for per_env in loop.values())
    assert closed - 1 > 5 * (opened - 1)
    # the committed runs: at epoch 10 every v1 run has moved the cube in more of its stored
    # episodes than any v4 HER-EBP-CS run, torquescale 4 included; v4's HER and HER-CS runs
    # are within v1's range or above it, never below
    rows = result["committed"]
    v1_shares = [r["share"]["10"] for r in rows if r["env"] == "v1"]
    v4_ebp = [r["share"]["10"] for r in rows
              if r["env"].startswith("v4") and r["method"] == "her-ebp-cs"]
    v4_plain = [r["share"]["10"] for r in rows
                if r["env"] == "v4" and r["method"] in ("her", "her-cs")]
    assert len(v1_shares) >= 11 and len(v4_ebp) >= 11 and len(v4_plain) >= 4
    assert min(v1_shares) > max(v4_ebp)
    assert min(v4_plain) > max(v4_ebp) and min(v4_plain) >= min(v1_shares) - 0.01
