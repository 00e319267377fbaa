"""The errors a new user meets first (issue 23, item 8), met as they meet them: through the
`hercs` command, in a folder of their own. Each message names what is wrong, where, and what
to do; each test asserts the text."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

from hercs.apps.cli.main import main
from hercs.config import HercsConfig, save_yaml
from hercs.run.rundir import RunDir

CONFIG_HINT = "(`hercs config -o FILE` writes the full default config to start from)"
NOT_BOOLEAN = "must be true or false (yes, no, on and off are not taken as booleans)"
RUN_HOLDS = ("config.yaml, metrics.csv, episodes.mcap and checkpoints/, which `hercs up` "
             "writes into runs/<run>/")


@pytest.fixture
def here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A user's working folder with a few files in it; the commands run there."""
    monkeypatch.chdir(tmp_path)
    files = {
        "bad.yaml": "ddpg:\n  lr_actor: [1\n",
        "tab.yaml": "ddpg:\n\tgamma: 0.9\n",
        "typo.yaml": "ddpg:\n  lr_actr: 0.001\n",
        "section.yaml": "dpg:\n  lr_actor: 0.001\n",
        "yes.yaml": "security:\n  allow_insecure: yes\n",
        "range.yaml": "ddpg:\n  gamma: 1.5\n",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    (tmp_path / "notes").mkdir()  # a folder that is not a run
    run = tmp_path / "runs" / "reach-her-cs-s1"  # a run that has not finished epoch 1
    RunDir(run).checkpoints.mkdir(parents=True)
    save_yaml(HercsConfig(), RunDir(run).config)
    return tmp_path


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--config", "bad.yaml"],
         "config file 'bad.yaml', line 3, column 1: not valid YAML (expected ',' or ']', but "
         "got '<stream end>', while parsing a flow sequence that begins at line 2, column 13); "
         f"fix the file there {CONFIG_HINT}"),
        (["--config", "tab.yaml"],
         "config file 'tab.yaml', line 2, column 1: not valid YAML (found character '\\t' that "
         f"cannot start any token); fix the file there {CONFIG_HINT}"),
        (["--config", "nosuch.yaml"],
         f"config file 'nosuch.yaml': no such file; give the path of a YAML config {CONFIG_HINT}"),
        (["--config", "notes"],
         "config file 'notes': is a folder, not a YAML file (a run folder's config is its "
         "config.yaml; `hercs up --resume RUN` continues a run)"),
        (["--config", "typo.yaml"],
         "config file 'typo.yaml': unknown key 'ddpg.lr_actr'; did you mean 'ddpg.lr_actor'? "
         "known in ddpg: ['action_l2', 'batch_size',"),
        (["--config", "section.yaml"],
         "config file 'section.yaml': unknown section 'dpg'; did you mean 'ddpg'? known: "
         "['actor', 'cluster', 'ddpg',"),
        (["--config", "yes.yaml"],
         f"config file 'yes.yaml': security.allow_insecure: got 'yes', {NOT_BOOLEAN}"),
        (["--config", "range.yaml"],
         "config file 'range.yaml': ddpg.gamma: got 1.5, must lie in (0, 1)"),
        (["--set", "ddpg.lr_actr=1e-3"],
         "override 'ddpg.lr_actr=1e-3': unknown field 'ddpg.lr_actr'; did you mean "
         "'ddpg.lr_actor'? known in ddpg: ['action_l2',"),
        (["--set", "ddpg.lr=1e-3"],  # nothing close: the list alone
         "override 'ddpg.lr=1e-3': unknown field 'ddpg.lr'; known in ddpg: ['action_l2',"),
        (["--set", "dpg.lr_actor=1e-3"],
         "override 'dpg.lr_actor=1e-3': unknown section 'dpg'; did you mean 'ddpg'? known:"),
        (["--set", "security.allow_insecure=yes"],
         f"security.allow_insecure: got 'yes', {NOT_BOOLEAN}"),
        (["--set", "security.allow_insecure=on"],
         f"security.allow_insecure: got 'on', {NOT_BOOLEAN}"),
        (["--set", "replay.free_run=off"], f"replay.free_run: got 'off', {NOT_BOOLEAN}"),
        (["--set", "replay.free_run=1"], "replay.free_run: got 1, must be true or false"),
    ],
    ids=["bad-yaml", "yaml-tab", "no-such-file", "config-is-a-folder", "yaml-unknown-key",
         "yaml-unknown-section", "yaml-yes", "yaml-bad-value", "set-unknown-field",
         "set-unknown-field-nothing-close", "set-unknown-section", "set-yes", "set-on",
         "set-off", "set-1"])
def test_a_bad_config_is_refused_naming_file_field_and_fix(here: Path, argv: list[str],
                                                           message: str, capsys) -> None:
    assert main(["config", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hercs config: invalid configuration: ")
    assert message in err


@pytest.mark.parametrize("value", ["true", "false", "True", "FALSE"])
def test_booleans_are_true_or_false(here: Path, value: str, capsys) -> None:
    assert main(["config", "--set", f"security.allow_insecure={value}"]) == 0
    resolved = yaml.safe_load(capsys.readouterr().out)
    assert resolved["security"]["allow_insecure"] is (value.lower() == "true")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["eval", "runs/reach-her-cs-s1"],
         "hercs eval: runs/reach-her-cs-s1: no checkpoint best (best.pt, the default) and no "
         "learner.pt yet: runs/reach-her-cs-s1/checkpoints holds none. best.pt (best, the "
         "best-evaluated epoch's policy) is written once the run's first epoch has been "
         "evaluated, learner.pt (latest) at every epoch end; wait for epoch 1 to finish "
         "(metrics.csv gets its row), or give another run\n"),
        (["eval", "runs/reach-her-cs-s1", "--checkpoint", "epoch-10"],
         "hercs eval: runs/reach-her-cs-s1: no checkpoint epoch-10 (epoch-0010.pt) yet: "),
        (["eval", "notes"],
         f"hercs eval: notes: not a run directory: it has no config.yaml (a run directory "
         f"holds {RUN_HOLDS}); run directories in runs: reach-her-cs-s1\n"),
        (["eval", "runs"],
         f"hercs eval: runs: not a run directory: it has no config.yaml (a run directory holds "
         f"{RUN_HOLDS}); it holds run directories: reach-her-cs-s1; give one of them\n"),
        (["eval", "runs/reach-her-cs-1"],
         "hercs eval: runs/reach-her-cs-1: no such folder; give a run directory, the folder "
         "`hercs up` made as runs/<run>/; did you mean runs/reach-her-cs-s1?\n"),
        (["eval", "bad.yaml"],
         f"hercs eval: bad.yaml: a file, not a run directory; give the folder that holds "
         f"{RUN_HOLDS}\n"),
        (["eval", "runs/reach-her-cs-s1", "--checkpoint", "mine.pt"],
         "hercs eval: checkpoint mine.pt: no such file; give best, latest, epoch-N or a .pt "
         "file's path\n"),
        (["plot", "notes", "-o", "fig.png"],
         f"hercs plot: notes: not a run directory: it has no config.yaml (a run directory "
         f"holds {RUN_HOLDS}); run directories in runs: reach-her-cs-s1\n"),
        (["plot", "runs/reach-her-cs-s1", "-o", "fig.png"],
         "hercs plot: runs/reach-her-cs-s1: this run has no metrics.csv yet; the learner "
         "writes its first row when epoch 1 has been evaluated; wait for that, or look at a "
         "finished run\n"),
    ],
    ids=["eval-no-checkpoint-yet", "eval-no-such-epoch", "eval-not-a-run",
         "eval-folder-of-runs", "eval-typo", "eval-a-file", "eval-no-such-file",
         "plot-not-a-run", "plot-no-metrics-yet"])
def test_a_folder_that_is_no_run_or_has_no_checkpoint_says_what_to_do(
        here: Path, argv: list[str], message: str, capsys) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err, err


def test_eval_names_the_checkpoints_a_run_has(here: Path, capsys) -> None:
    checkpoints = RunDir(here / "runs" / "reach-her-cs-s1").checkpoints
    for name in ("learner.pt", "epoch-0010.pt", "epoch-0020.pt"):
        (checkpoints / name).write_bytes(b"")
    assert main(["eval", "runs/reach-her-cs-s1", "--checkpoint", "best"]) == 2
    assert capsys.readouterr().err == (
        "hercs eval: runs/reach-her-cs-s1: no checkpoint best (best.pt); "
        "runs/reach-her-cs-s1/checkpoints holds latest (learner.pt), epoch-10 "
        "(epoch-0010.pt), epoch-20 (epoch-0020.pt): ask for one of those (best, latest, "
        "epoch-N or a .pt file's path)\n")


def _copied_run(here: Path, name: str) -> Path:
    """What a committed run holds (docs/results/runs/<run>/): its config and every epoch's
    metrics row, no checkpoint and no episode log."""
    run = here / "runs" / name
    run.mkdir()
    save_yaml(HercsConfig(), RunDir(run).config)
    RunDir(run).metrics.write_text("epoch,success_rate\n" +
                                     "".join(f"{e},0.{e}\n" for e in range(1, 4)))
    return run


def test_eval_of_a_copied_run_says_its_checkpoints_were_not_kept(here: Path, capsys) -> None:
    _copied_run(here, "reach-her-cs-s2")
    RunDir(here / "runs" / "reach-her-s5").checkpoints.mkdir(parents=True)  # another cell
    RunDir(here / "runs" / "reach-her-s5").checkpoint("best").write_bytes(b"")
    RunDir(here / "runs" / "reach-her-cs-s1").checkpoint("best").write_bytes(b"")
    assert main(["eval", "runs/reach-her-cs-s2"]) == 2
    assert capsys.readouterr().err == (
        "hercs eval: runs/reach-her-cs-s2: no checkpoint best (best.pt, the default) and no "
        "learner.pt: runs/reach-her-cs-s2/checkpoints does not exist, though metrics.csv "
        "records 3 trained epochs: this folder is a copy of the run without its checkpoints "
        "(a copied or committed run often keeps only config.yaml and metrics.csv). Evaluate "
        "the folder where it trained, or give a policy file (--checkpoint FILE.pt); runs "
        "beside it with a policy (best.pt): runs/reach-her-cs-s1, runs/reach-her-s5; its "
        "learning curve is in metrics.csv (hercs plot runs/reach-her-cs-s2 -o fig.png)\n")


def test_read_episodes_says_whether_a_log_is_still_to_come(here: Path) -> None:
    import hercs

    copied = _copied_run(here, "reach-her-cs-s2")
    with pytest.raises(hercs.HercsError) as never:
        next(hercs.read_episodes(copied))
    assert str(never.value) == (
        f"{copied}: this run has no episode log (episodes.mcap or episodes.NNN.mcap), and "
        "never will here: its metrics.csv records 3 trained epochs, so the run wrote its files "
        "where it trained, and this folder is a copy without them (a copied or committed run "
        "often keeps only config.yaml and metrics.csv); use the folder where it trained, or a "
        "run that has one")
    starting = here / "runs" / "reach-her-cs-s1"  # no epoch evaluated yet
    with pytest.raises(hercs.HercsError) as not_yet:
        next(hercs.read_episodes(starting))
    assert str(not_yet.value) == (
        f"{starting}: this run has no episode log (episodes.mcap or episodes.NNN.mcap) yet; "
        "the replay writes it from the run's first episode on; wait for the run to start, or "
        "look at another run")


def test_an_actor_without_connect_says_where_it_connects_and_how_to_change_it(
        here: Path) -> None:
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "actor", "--run", "nosuchrun",
                           "--set", "transport.wait_s=0.2"], cwd=here, capture_output=True,
                          text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[3])})
    assert done.returncode == 3  # the service gave up after transport.wait_s, and said so
    assert done.stderr.startswith(
        "hercs actor: no runs/nosuchrun/router.json (no run nosuchrun is running in runs): "
        "connecting to tcp/127.0.0.1:7447 (the default transport.connect) and waiting for a "
        "router there; give --connect ENDPOINT (the run's router, e.g. tls/HOST:7447), or "
        "--run-dir DIR if the run's folder is elsewhere\n"), done.stderr
    assert "no Zenoh router reachable at ['tcp/127.0.0.1:7447']" in done.stderr
