"""`hercs.up()` builds its config as a tree in Python (`hercs.config.with_values`) and hands it
to `hercs up` whole: it must be the config the command line builds from the same choices, and
refuse what the command refuses, by name, before anything starts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from hercs.apps.cli.config_flags import resolve_config
from hercs.apps.cli.main import build_parser
from hercs.apps.cli.run_handle import _built
from hercs.config import HercsConfig, apply_overrides, save_yaml, with_values
from hercs.errors import ConfigError

LOOPBACK = "tcp/127.0.0.1:0"


def command(*argv: str) -> HercsConfig:
    return resolve_config(build_parser()[0].parse_args(["up", *argv]))


def python(**given: Any) -> HercsConfig:
    arguments: dict[str, Any] = dict.fromkeys(["task", "method", "epochs", "seed", "actors",
                                               "name", "run_dir", "config"])
    arguments.update(overrides=(), listen=LOOPBACK)
    arguments.update(given)
    return _built(**arguments)


def test_the_named_arguments_and_a_dict_build_what_the_flags_and_set_build(
        tmp_path: Path) -> None:
    typed = python(task="reach", method="her-cs", epochs=3, seed=2, actors=2, name="007",
                   run_dir=tmp_path, track="tensorboard",
                   overrides={"ddpg.lr_actor": 5e-4, "view.live": True,
                              "transport.connect": ["tcp/10.0.0.2:7447"],
                              "cluster.k": 4})
    flags = command("--task", "reach", "--method", "her-cs", "--epochs", "3", "--seed", "2",
                    "--actors", "2", "--run", "007", "--run-dir", str(tmp_path),
                    "--listen", LOOPBACK, "--track", "tensorboard",
                    "--set", "ddpg.lr_actor=5e-4", "--set", "view.live=true",
                    "--set", "transport.connect=[tcp/10.0.0.2:7447]", "--set", "cluster.k=4")
    assert typed == flags
    assert typed.run.name == "007" and typed.ddpg.lr_actor == 5e-4 and typed.cluster.k == 4


def test_a_file_then_set_strings_build_what_the_command_builds(tmp_path: Path) -> None:
    saved = apply_overrides(HercsConfig(), ["task.name=push", "ddpg.batch_size=64"])
    save_yaml(saved, tmp_path / "c.yaml")
    typed = python(config=tmp_path / "c.yaml", epochs=5,
                   overrides=["ddpg.batch_size=128", "run.name=1e-5"])
    flags = command("--config", str(tmp_path / "c.yaml"), "--epochs", "5", "--listen",
                    LOOPBACK, "--set", "ddpg.batch_size=128", "--set", "run.name=1e-5")
    assert typed == flags
    assert (typed.task.name, typed.ddpg.batch_size, typed.run.name) == ("push", 128, "1e-5")


@pytest.mark.parametrize(("overrides", "message"), [
    ({"ddpg.lr_actr": 1e-3}, r"unknown field 'ddpg\.lr_actr'.*ddpg\.lr_actor"),
    ({"dpg.lr_actor": 1e-3}, r"unknown section 'dpg'.*ddpg"),
    ({"lr_actor": 1e-3}, r"'lr_actor' \(= 0\.001\): the key must look like section\.field"),
    ({"ddpg.batch_size": "many"}, r"ddpg\.batch_size"),
    ({"training.epochs": float("nan")}, r"training\.epochs"),
    (["ddpg.lr_actr=1e-3"], r"override 'ddpg\.lr_actr=1e-3': unknown field"),
    ("ddpg.lr_actor=1e-3", "not the string"),
], ids=["field", "section", "no-dot", "type", "nan", "string-item", "a-string"])
def test_a_bad_key_or_value_is_refused_by_name(overrides: Any, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        python(task="reach", overrides=overrides)


@pytest.mark.parametrize(("given", "message"), [
    ({"actors": "two"}, r"actor\.num_actors: got 'two', must be a number"),
    ({"epochs": 2.5}, r"training\.epochs: got 2\.5, must be an integer"),
    ({"seed": True}, r"run\.seed: got True, must be an integer"),
    ({"task": "no-such-task"}, r"task\.name: got 'no-such-task'"),
], ids=["actors", "epochs", "seed", "task"])
def test_a_bad_named_argument_is_refused_naming_the_field_it_sets(
        given: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        python(**given)


def test_with_values_leaves_the_config_it_was_given_as_it_was() -> None:
    base = HercsConfig()
    changed = with_values(base, {"ddpg.hidden_size": 64, "transport.listen": ("tcp/a:1",)})
    assert (changed.ddpg.hidden_size, changed.transport.listen) == (64, ["tcp/a:1"])
    assert base == HercsConfig()


def test_a_config_file_naming_code_is_trusted_before_it_is_built(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """As on the command line, `config=`'s own task name is trusted (the user named the file)
    before the config is built, since building it imports the code the name names."""
    from hercs.rl.code_names import TRUST_ENV

    monkeypatch.delenv(TRUST_ENV, raising=False)
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "lab_envs.py").write_text(
        "import gymnasium as gym\n\n\ndef make():\n    return gym.make('FetchReach-v4')\n")
    (tmp_path / "c.yaml").write_text("task:\n  name: lab_envs:make\n")
    built = python(config=tmp_path / "c.yaml")
    assert built.task.name == "lab_envs:make"
    assert built.task.spec.goal_dim == 3
