"""The CLI resolves one config and refuses bad flags with a message naming the field."""

import argparse
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from hercs.apps.cli.main import build_parser, main

REPO = Path(__file__).resolve().parents[3]


def test_config_command_resolves_shortcuts_and_overrides(capsys) -> None:
    assert main(["config", "--task", "slide", "--method", "her-ebp", "--seed", "5",
                 "--set", "ddpg.polyak=0.9", "--connect", "tcp/10.0.0.2:7447"]) == 0
    resolved = yaml.safe_load(capsys.readouterr().out)
    assert resolved["task"]["name"] == "slide"
    assert resolved["run"]["method"] == "her-ebp" and resolved["run"]["seed"] == 5
    assert resolved["ddpg"]["polyak"] == 0.9
    assert resolved["transport"]["connect"] == ["tcp/10.0.0.2:7447"]


def test_config_command_says_the_epsilon_an_unset_field_resolves_to(capsys) -> None:
    """energy.epsilon stays null in the printed tree (a file made from it and run on v1 gets
    v1's); a comment says the number this config's env version gives."""
    for flags, number in (([], "0.001 with task.env_version v4"),
                          (["--set", "task.env_version=v1"], "1e-06 with task.env_version v1")):
        assert main(["config", *flags]) == 0
        out = capsys.readouterr().out
        assert yaml.safe_load(out)["energy"]["epsilon"] is None
        assert f"# energy.epsilon null: the simulator's, {number}" in out
    assert main(["config", "--set", "energy.epsilon=2e-4"]) == 0
    out = capsys.readouterr().out
    assert yaml.safe_load(out)["energy"]["epsilon"] == 2e-4 and "# energy.epsilon" not in out


def test_bad_config_value_exits_2_with_field_named(capsys) -> None:
    assert main(["config", "--set", "ddpg.gamma=2"]) == 2
    assert "ddpg.gamma: got 2.0" in capsys.readouterr().err


def test_console_script_help_lists_commands() -> None:
    out = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "--help"], capture_output=True,
                         text=True, check=True).stdout
    assert "config" in out


def test_version_names_the_package_and_the_commit_of_a_checkout(tmp_path: Path) -> None:
    """From this checkout: the version and its commit; from a copy of the package outside any
    checkout (as pip installs it): the version alone."""
    import hercs

    def head() -> str:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, check=True,
                              capture_output=True, text=True).stdout.strip()

    before = head()
    here = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "--version"], cwd=REPO,
                          capture_output=True, text=True, check=True)
    commits = "|".join(re.escape(c) for c in {before, head()})  # a commit made meanwhile
    assert re.fullmatch(rf"hercs {re.escape(hercs.__version__)}, commit ({commits})"
                        r"( \(with uncommitted changes\))?\n", here.stdout), here.stdout
    shutil.copytree(REPO / "hercs", tmp_path / "hercs",
                    ignore=shutil.ignore_patterns("__pycache__"))
    installed = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "--version"],
                               cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(tmp_path)},
                               capture_output=True, text=True, check=True)
    assert installed.stdout == f"hercs {hercs.__version__}\n"


TAKE_CONFIG = {"config", "up", "slurm submit", "router", "replay", "clusterer", "learner",
               "evaluator", "actor", "live"}
"""The commands README's "Configuration" says take --config and --set (sweep: --set only)."""


def test_the_commands_the_readme_names_take_config_and_set_and_no_other() -> None:
    """README's "Configuration": the commands that make or join a run take --config and
    --set, `hercs sweep` takes --set for its runs, and the others refuse both (exit 2)."""
    parser, _ = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    taking = set()
    for name, command in sub.choices.items():
        inner = [a for a in command._actions if isinstance(a, argparse._SubParsersAction)]
        for full, each in ([(f"{name} {n}", c) for n, c in inner[0].choices.items()] if inner
                           else [(name, command)]):
            if {"--config", "--set"} <= {f for a in each._actions for f in a.option_strings}:
                taking.add(full)
    assert taking == TAKE_CONFIG
    assert ("(`config`, `up`, `slurm submit`, `router` and the services) take\n`--config "
            "FILE.yaml` and `--set section.field=value`") in (REPO / "README.md").read_text()
    sweep = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "sweep", "--help"],
                           cwd=REPO, capture_output=True, text=True, check=True).stdout
    assert "--set SECTION.FIELD=VALUE" in sweep and "--config" not in sweep
    for command in (["plot", "r", "-o", "x.png"], ["eval", "r"], ["view", "r"],
                    ["certs", "d"]):
        refused = subprocess.run([sys.executable, "-m", "hercs.apps.cli", *command, "--set",
                                  "ddpg.polyak=0.9"], cwd=REPO, capture_output=True, text=True)
        assert refused.returncode == 2, command
        assert "unrecognized arguments: --set ddpg.polyak=0.9" in refused.stderr, command


@pytest.mark.parametrize(
    ("flags", "view"),
    [([], {"live": False, "episode_every": 20, "viewer": "spawn", "save": ""}),
     (["--rerun"], {"live": True, "episode_every": 20, "viewer": "spawn", "save": ""}),
     (["--rerun", "9877", "--rerun-every", "5"],
      {"live": True, "episode_every": 5, "viewer": "rerun+http://127.0.0.1:9877/proxy",
       "save": ""}),
     (["--rerun", "rerun+https://lab:9876/proxy", "--rerun-save", "out/live.rrd"],
      {"live": True, "episode_every": 20, "viewer": "rerun+https://lab:9876/proxy",
       "save": "CWD/out/live.rrd"}),
     (["--rerun-save", "live.rrd"],
      {"live": True, "episode_every": 20, "viewer": "none", "save": "CWD/live.rrd"})],
    ids=["off", "spawn", "port", "url-and-file", "file-only"],
)
def test_rerun_flags_set_the_view_section(flags: list[str], view: dict, tmp_path: Path,
                                          monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["config", *flags]) == 0
    resolved = yaml.safe_load(capsys.readouterr().out)["view"]
    assert resolved == {k: v.replace("CWD", str(tmp_path)) if isinstance(v, str) else v
                        for k, v in view.items()}


def test_a_bad_rerun_url_exits_2_with_the_value_named(capsys) -> None:
    assert main(["config", "--rerun", "http://lab:9876"]) == 2
    assert "view.viewer: got 'http://lab:9876'" in capsys.readouterr().err


@pytest.mark.parametrize(("command", "absent", "present"), [
    ("router", ["--task", "--actors", "--connect", "--epochs"], ["--listen", "--tls-dir"]),
    ("actor", ["--task", "--actors", "--listen", "--method"], ["--run", "--connect", "--id"]),
    ("learner", ["--actors", "--listen"], ["--task", "--run", "--connect"]),
    ("up", ["--connect"], ["--actors", "--listen", "--resume", "--tensorboard"]),
])
def test_each_command_offers_only_its_own_flags(command: str, absent: list[str],
                                               present: list[str]) -> None:
    parser, _ = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    help_text = sub.choices[command].format_help()
    assert "Example: hercs" in help_text, "a description with an example"
    for flag in absent:
        assert f"{flag} " not in help_text, f"hercs {command} lists {flag}"
    for flag in present:
        assert flag in help_text
    with pytest.raises(SystemExit) as exc:
        parser.parse_args([command, absent[0], "x"])
    assert exc.value.code == 2


def _resolved(capsys, *flags: str) -> dict:
    assert main(["config", *flags]) == 0
    return yaml.safe_load(capsys.readouterr().out)


def test_workers_preset_scales_episodes_batch_and_actors(capsys, tmp_path: Path) -> None:
    """--workers N: N× episodes per cycle and N× minibatch of whatever the config holds,
    N actors; updates per cycle unchanged; an explicit --actors or --set still wins."""
    one = _resolved(capsys)
    four = _resolved(capsys, "--workers", "4")
    assert four["training"]["episodes_per_cycle"] == 4 * one["training"]["episodes_per_cycle"]
    assert four["ddpg"]["batch_size"] == 4 * one["ddpg"]["batch_size"] == 1024
    assert four["actor"]["num_actors"] == 4
    assert four["training"]["minibatches_per_cycle"] == one["training"]["minibatches_per_cycle"]
    partial = tmp_path / "small.yaml"
    partial.write_text("ddpg: {batch_size: 64}\n")
    scaled = _resolved(capsys, "--config", str(partial), "--workers", "2", "--actors", "6",
                       "--set", "training.episodes_per_cycle=3")
    assert scaled["ddpg"]["batch_size"] == 128
    assert scaled["actor"]["num_actors"] == 6 and scaled["training"]["episodes_per_cycle"] == 3
    assert main(["config", "--workers", "0"]) == 2
    assert "--workers: got 0" in capsys.readouterr().err
    assert main(["up", "--resume", str(tmp_path), "--workers", "2"]) == 2
    assert "--workers" in capsys.readouterr().err


EXIT_AFTER_CLOSE_SCRIPT = """
import logging, sys, threading
from hercs.apps.cli.services import exit_after_close
logging.basicConfig(level=logging.INFO, format="%(message)s")
release = threading.Event()
def late_writer():
    release.wait()
    print("non-daemon thread done", flush=False)
threading.Thread(target=late_writer).start()
threading.Thread(target=threading.Event().wait, daemon=True).start()  # never ends
logging.getLogger("svc").info("service closed")
sys.stdout.write("buffered, not flushed")
threading.Timer(0.2, release.set).start()
exit_after_close(3)
"""


def test_exit_after_close_keeps_the_status_waits_for_non_daemon_threads_and_flushes() -> None:
    # What a service process does once its run returned: the status is the run's, output
    # still buffered is written, a non-daemon thread is waited for, a daemon one is not.
    done = subprocess.run([sys.executable, "-c", EXIT_AFTER_CLOSE_SCRIPT], capture_output=True,
                          text=True, timeout=60, cwd=Path(__file__).resolve().parents[3])
    assert done.returncode == 3, done.stderr
    assert "service closed" in done.stderr
    assert "buffered, not flushed" in done.stdout and "non-daemon thread done" in done.stdout


@pytest.mark.parametrize("command", ["up", "actor", "evaluator"])
def test_a_v1_run_without_mujoco_py_exits_2_before_it_starts(command: str, tmp_path: Path,
                                                             capsys, monkeypatch) -> None:
    import hercs.rl.envs

    monkeypatch.setattr(hercs.rl.envs, "mujoco_py_problem", lambda: "mujoco_py is not installed")
    assert main([command, "--set", "task.name=reach", "--set", "task.env_version=v1",
                 "--set", f"run.run_dir={tmp_path}", "--set", "run.name=v1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"hercs {command}: task.env_version: got 'v1', but FetchReach-v1 "
                          "runs on mujoco-py (MuJoCo 2.1) and mujoco_py is not installed; "
                          "`make mujoco-py` in the hercs checkout installs it"), err
    assert not any(tmp_path.iterdir()), "nothing started"


def _joined(argv: list[str]):
    from hercs.apps.cli.main import join_endpoints, resolve_config

    args = build_parser()[0].parse_args(argv)
    return join_endpoints(args, resolve_config(args))


def test_actor_and_live_find_the_router_in_the_run_directory(tmp_path: Path) -> None:
    import socket

    from hercs.run import router_record
    run = tmp_path / "r1"
    run.mkdir()
    router_record.write_router(run, router_record.RouterRecord.for_listen(["tls/0.0.0.0:4321"]))
    for command in ("actor", "live"):
        joined = _joined([command, "--run", "r1", "--run-dir", str(tmp_path)])
        assert joined.transport.connect == ["tls/127.0.0.1:4321"], command  # same host
    router_record.write_router(run, router_record.RouterRecord.for_listen(
        ["tls/0.0.0.0:4321"], host=f"not-{socket.gethostname()}"))
    joined = _joined(["actor", "--run", "r1", "--run-dir", str(tmp_path)])
    assert joined.transport.connect == [f"tls/not-{socket.gethostname()}:4321"]
    # an explicit --connect wins over the file
    joined = _joined(["actor", "--run", "r1", "--run-dir", str(tmp_path),
                      "--connect", "tcp/10.0.0.9:1"])
    assert joined.transport.connect == ["tcp/10.0.0.9:1"]


def test_a_joiner_gives_up_after_transport_wait_s_without_a_router(tmp_path: Path,
                                                                   capsys) -> None:
    assert main(["actor", "--run", "gone", "--run-dir", str(tmp_path),
                 "--set", "transport.wait_s=0.5"]) == 3
    err = capsys.readouterr().err
    assert f"no router recorded in {tmp_path / 'gone'} after 0.5 s" in err


def test_run_dir_without_run_names_the_flag(capsys) -> None:
    assert main(["live", "--run-dir", "runs"]) == 2
    assert "--run-dir: give --run RUN too" in capsys.readouterr().err


def test_a_mistyped_flag_is_told_by_its_command_with_the_flag_meant() -> None:
    """`hercs up --epocs 3` (issue 58): the usage of `hercs up`, not the top-level one, and
    the flag it most likely meant; exit 2 as every other refused flag."""
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "up", "--epocs", "3"],
                          cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith("usage: hercs up "), done.stderr
    assert "hercs up: error: unrecognized arguments: --epocs 3" in done.stderr
    assert done.stderr.rstrip().endswith("--epocs: did you mean --epochs?"), done.stderr
