"""The CLI resolves one config and refuses bad flags with a message naming the field."""

import subprocess
import sys

import yaml

from hercs.cli import main


def test_config_command_resolves_shortcuts_and_overrides(capsys) -> None:
    assert main(["config", "--task", "slide", "--method", "her-ebp", "--seed", "5",
                 "--set", "ddpg.polyak=0.9", "--connect", "tcp/10.0.0.2:7447"]) == 0
    resolved = yaml.safe_load(capsys.readouterr().out)
    assert resolved["task"]["name"] == "slide"
    assert resolved["run"]["method"] == "her-ebp" and resolved["run"]["seed"] == 5
    assert resolved["ddpg"]["polyak"] == 0.9
    assert resolved["transport"]["connect"] == ["tcp/10.0.0.2:7447"]


def test_bad_config_value_exits_2_with_field_named(capsys) -> None:
    assert main(["config", "--set", "ddpg.gamma=2"]) == 2
    assert "ddpg.gamma: got 2.0" in capsys.readouterr().err


def test_console_script_help_lists_commands() -> None:
    out = subprocess.run([sys.executable, "-m", "hercs.cli", "--help"], capture_output=True,
                         text=True, check=True).stdout
    assert "config" in out
