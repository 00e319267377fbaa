"""`hercs up` (hercs.apps.launch.launcher), its pure parts: progress lines, run resolution, the
planned children, refusals before anything starts.

Stand-in children (the `up` fixture): test_launcher_processes.py; the real services end to
end: test_launcher_services.py.
"""

from __future__ import annotations

import socket
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import pytest

from hercs.apps.cli.main import build_parser, main, resolve_config
from hercs.apps.launch.progress import Progress
from hercs.apps.launch.router import free_port
from hercs.apps.launch.run_plan import child_argv, plan_children, resolve_run
from hercs.config import HercsConfig
from hercs.proto import hercs_pb2 as pb
from hercs.run.rundir import RunDir
from tests.integration.launcher_standins import REPO, WAIT_S
from tests.support import Clock

pytestmark = pytest.mark.integration


def test_progress_prints_one_line_per_epoch_and_waits_for_the_eval() -> None:
    clock = Clock(1000.0)
    progress = Progress(total_epochs=10, clock=clock)
    base = {"env_steps_per_s": 1234.4, "updates_per_s": 456.2, "replay_size": 6000,
            "policy_lag": 1.23}

    clock.now += 100  # the first epoch seen (3: a resumed run) took 100 s: 7 more, 700 s
    assert progress.on_metrics("learner/learner-0", {**base, "epoch": 3,
                                                     "success_rate": 0.45}) == [
        "epoch 3/10  success 0.45  env 1234 steps/s  upd 456/s  replay 6000  lag 1.2  "
        "eta 11m40s"]
    assert progress.on_metrics("learner/learner-0", {**base, "epoch": 3}) == []  # duplicate
    assert progress.on_metrics("actor/actor-0", {"epoch": 4}) == []  # not the learner
    # no success yet: the line waits for its EvalResult...
    assert progress.on_metrics("learner/learner-0", {**base, "epoch": 4}) == []
    progress.actors = 2
    clock.now += 100
    assert progress.on_eval(4, 0.5) == [
        "epoch 4/10  success 0.50  env 1234 steps/s  upd 456/s  replay 6000  lag 1.2  "
        "actors 2  eta 10m00s"]
    # ...or for the next epoch's metrics, or the final flush
    progress.on_replay_status(pb.ReplayStatus(size_episodes=7000))
    progress.actors = None
    assert progress.on_metrics("learner/learner-0", {"epoch": 5}) == []
    assert progress.on_metrics("learner/learner-0", {"epoch": 6, "success_rate": 1.0}) == [
        "epoch 5/10  success -  env - steps/s  upd -/s  replay 7000  lag -  eta 5m33s",
        "epoch 6/10  success 1.00  env - steps/s  upd -/s  replay 7000  lag -  eta 3m20s"]
    assert progress.on_metrics("learner/learner-0", {"epoch": 7, "epochs": 8}) == []
    assert progress.flush() == [
        "epoch 7/8  success -  env - steps/s  upd -/s  replay 7000  lag -  eta 40s"]
    assert progress.last_printed == 7


def test_progress_line_shows_each_actors_share_of_the_epochs_episodes() -> None:
    """With several actors, the epoch line gives each one's share of the episodes stored
    since the previous line (actor-id order); one contributing actor: just the count."""
    clock = Clock(1000.0)
    progress = Progress(total_epochs=3, clock=clock)
    progress.actors = 3
    for actor, n in (("actor-1", 30), ("actor-0", 60), ("remote-a", 10)):
        for _ in range(n):
            progress.on_inserted(actor)
    clock.now += 10
    [line] = progress.on_metrics("learner/learner-0", {"epoch": 1, "success_rate": 0.1})
    assert "  actors 3 (60/30/10 %)  " in line
    progress.on_inserted("actor-0")
    [line] = progress.on_metrics("learner/learner-0", {"epoch": 2, "success_rate": 0.2})
    assert "  actors 3  " in line and "%" not in line  # counted afresh for each line


def test_a_cluster_methods_lines_carry_its_model_and_episodes_per_cluster() -> None:
    """Before the first model: the failed goals counted towards it (the clusterer's count,
    capped at the fit's size); then the replay's model version and its episodes per cluster;
    the last line names the command that shows them. A method without clusters says
    nothing of them."""
    progress = Progress.for_run(HercsConfig.from_dict({"cluster": {"k": 4, "fgb_size": 40}}))
    progress.on_metrics("clusterer/clusterer-0", {"failed_goals_seen": 12, "episodes_seen": 30})
    [line] = progress.on_metrics("learner/learner-0", {"epoch": 1, "success_rate": 0.1})
    assert line.endswith("  clusters none yet (12/40 failed goals)  eta 0s")
    progress.on_replay_status(pb.ReplayStatus(size_episodes=90, cluster_model_version=3,
                                              cluster_sizes=[60, 0, 26, 4]))
    [line] = progress.on_metrics("learner/learner-0", {"epoch": 2, "success_rate": 0.2})
    assert "  replay 90  lag -  clusters v3 [60 0 26 4]  eta " in line
    assert progress.finished_lines("r", Path("runs/my run")) == [
        "hercs up: run r finished; run directory: runs/my run; its episodes and clusters: "
        "hercs view 'runs/my run'"]

    plain = Progress.for_run(HercsConfig.from_dict({"run": {"method": "her"}}))
    plain.on_replay_status(pb.ReplayStatus(size_episodes=90, cluster_sizes=[0] * 8))
    [line] = plain.on_metrics("learner/learner-0", {"epoch": 1, "success_rate": 0.1})
    assert "clusters" not in line
    assert plain.finished_lines("r", Path("runs/r")) == [
        "hercs up: run r finished; run directory: runs/r; its episodes: hercs view runs/r"]


@pytest.mark.parametrize("success, why", [
    (1.0, " (its evaluated success reached 1.00 at epoch 1, so few episodes failed)"),
    (0.3, ""),
], ids=["solved", "not-solved"])
def test_a_cluster_run_that_never_fitted_a_model_says_why_at_its_end(success: float,
                                                                     why: str) -> None:
    progress = Progress.for_run(HercsConfig())
    progress.on_replay_status(pb.ReplayStatus(size_episodes=400, cluster_sizes=[0] * 8))
    progress.on_metrics("learner/learner-0", {"epoch": 1, "success_rate": success})
    progress.on_metrics("clusterer/clusterer-0", {"failed_goals_seen": 12, "episodes_seen": 400})
    assert progress.finished_lines("r", Path("runs/r")) == [
        "hercs up: no cluster model: 12 failed goals in 400 episodes, a fit needs "
        f"cluster.fgb_size=150{why}; a longer run or a smaller --set cluster.fgb_size=N fits "
        "one",
        "hercs up: run r finished; run directory: runs/r; its episodes: hercs view runs/r"]


def test_the_epoch_line_counts_the_episodes_refused_as_bad_input() -> None:
    """The learner's `bad_episodes` (malformed or implausible inserts, not stale ones) shows
    on the epoch line and on the running lines after it, and nothing shows while it is 0."""
    from hercs.learner.learner_shell import bad_episodes

    assert bad_episodes("implausible:1;stale_policy:40;bad_shape:2") == 3
    assert bad_episodes("stale_policy:40;cycle_full:3") == 0
    clock = Clock(1000.0)
    progress = Progress(total_epochs=5, clock=clock)
    [line] = progress.on_metrics("learner/learner-0", {"epoch": 1, "success_rate": 0.1,
                                                       "bad_episodes": 0})
    assert "refused" not in line
    [line] = progress.on_metrics("learner/learner-0", {"epoch": 2, "success_rate": 0.2,
                                                       "bad_episodes": 1})
    assert line.endswith("  refused 1 bad episode"), line
    clock.now += 3600
    interim = progress.interim()
    assert interim is not None and interim.endswith("  refused 1 bad episode"), interim


def test_an_epoch_evaluated_after_a_later_one_is_still_printed_once() -> None:
    """An evaluator killed mid-epoch answers epochs 1 and 2 after epoch 3 (issue 57): their
    lines come late and say so, each once; an epoch printed with `success -` gets its late
    success the same way."""
    clock = Clock(1000.0)
    progress = Progress(total_epochs=4, clock=clock)
    [line] = progress.on_metrics("learner/learner-0", {"epoch": 3, "success_rate": 0.3})
    assert line.startswith("epoch 3/4  success 0.30")
    assert progress.on_metrics("learner/learner-0", {"epoch": 1, "success_rate": 0.1}) == [
        "epoch 1/4  success 0.10  (evaluated late, after epoch 3)"]
    assert progress.on_metrics("learner/learner-0", {"epoch": 1, "success_rate": 0.1}) == []
    assert progress.on_metrics("learner/learner-0", {"epoch": 2, "success_rate": 0.2}) == [
        "epoch 2/4  success 0.20  (evaluated late, after epoch 3)"]
    assert progress.on_metrics("learner/learner-0", {"epoch": 4}) == []  # waits for its eval
    [dash] = progress.flush()
    assert dash.startswith("epoch 4/4  success -")
    assert progress.on_eval(4, 0.4) == ["epoch 4/4  success 0.40  (evaluated late, after "
                                        "epoch 4)"]
    assert progress.on_eval(4, 0.4) == []


def test_progress_says_the_run_is_alive_before_the_first_epoch_ends() -> None:
    clock = Clock(1000.0)
    progress = Progress(total_epochs=200, clock=clock)
    assert progress.interim() is None
    clock.now += 5  # FIRST_LINE_S
    progress.on_replay_status(pb.ReplayStatus(size_episodes=12))
    progress.actors = 3
    assert progress.interim() == (
        "epoch 1/200 running  5s since start  replay 12 episodes  actors 3")
    clock.now += 59
    assert progress.interim() is None, "then at most once a minute"
    clock.now += 1
    assert progress.interim() is not None


@pytest.mark.parametrize(
    ("listen", "connect"),
    [("tcp/127.0.0.1:7447", "tcp/127.0.0.1:7447"),
     ("tcp/0.0.0.0:9000", "tcp/127.0.0.1:9000"),
     ("tcp/[::]:9000", "tcp/[::1]:9000"),
     ("tcp/10.1.2.3:7447", "tcp/10.1.2.3:7447")],
    ids=["loopback", "any-v4", "any-v6", "address"],
)
def test_resolve_run_names_the_run_and_points_children_at_the_router(listen: str,
                                                                     connect: str) -> None:
    config = resolve_config(build_parser()[0].parse_args(
        ["up", "--task", "pick", "--method", "her-ebp", "--seed", "7", "--listen", listen]))
    resolved = resolve_run(config, now=datetime(2025, 3, 4, 5, 6, 7))
    assert resolved.run.name == "pick-her-ebp-s7-20250304-050607"
    assert resolved.transport.connect == [connect]
    named = resolve_run(HercsConfig.from_dict({**config.to_dict(), "run": {"name": "mine"}}))
    assert named.run.name == "mine"
    # the children get, and the run saves, the ε it uses, not "the default"
    assert config.energy.epsilon is None and resolved.energy.epsilon == 1e-3


def test_children_are_planned_in_start_order_as_valid_hercs_commands(tmp_path: Path) -> None:
    config = resolve_config(build_parser()[0].parse_args(["up", "--actors", "3"]))
    specs = plan_children(config)
    assert [(s.role, s.ident) for s in specs] == [
        ("replay", "replay-0"), ("clusterer", "clusterer-0"), ("learner", "learner-0"),
        ("evaluator", "evaluator-0"), ("actor", "actor-0"), ("actor", "actor-1"),
        ("actor", "actor-2")]
    parser, commands = build_parser()
    for spec in specs:
        argv = child_argv(spec, RunDir(tmp_path).config)
        assert argv[:3] == [sys.executable, "-m", "hercs.apps.cli"]
        args = parser.parse_args(argv[3:])
        assert (args.command, args.ident, args.config) == (spec.role, spec.ident,
                                                           str(RunDir(tmp_path).config))
        assert args.command in commands


def test_up_refuses_a_run_directory_that_holds_files(tmp_path: Path, capsys) -> None:
    (tmp_path / "taken").mkdir()
    RunDir(tmp_path / "taken").episode_log.write_bytes(b"old")
    assert main(["up", "--run", "taken", "--run-dir", str(tmp_path)]) == 2
    assert "already exists and is not empty" in capsys.readouterr().err


def test_up_fails_clearly_when_the_router_port_is_taken(tmp_path: Path) -> None:
    port = free_port()
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", port))
        holder.listen()
        done = subprocess.run(
            [sys.executable, "-m", "hercs.apps.cli", "up", "--run", "x", "--run-dir",
             str(tmp_path), "--listen", f"tcp/127.0.0.1:{port}"],
            capture_output=True, text=True, timeout=WAIT_S, cwd=REPO)
    assert done.returncode == 1
    assert f"tcp/127.0.0.1:{port}" in done.stderr and "already in use" in done.stderr
    assert not (tmp_path / "x").exists()  # nothing written before the router is up
