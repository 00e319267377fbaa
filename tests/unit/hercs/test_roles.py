"""The one table of service roles (hercs/roles.py) and what is derived from it: the CLI's
service commands, `hercs up`'s children and stop stages, the certificates, the ACL."""

from __future__ import annotations

import importlib

from hercs.apps.cli.main import build_parser
from hercs.apps.launch.run_plan import plan_children
from hercs.apps.launch.supervisor import OPTIONAL_ROLES, STOP_STAGES
from hercs.config import HercsConfig, apply_overrides
from hercs.net.security import ROLE_GRANTS
from hercs.roles import ROLES, SERVICE_ROLES


def test_every_role_is_a_cli_command_running_its_module() -> None:
    parser, commands = build_parser()
    for role in SERVICE_ROLES.values():
        args = parser.parse_args([role.name, "--run", "r"])
        assert args.command == role.name and role.name in commands
        assert callable(importlib.import_module(role.module).run), role.module


def test_hercs_up_starts_the_replay_first_and_stops_it_last() -> None:
    config = apply_overrides(HercsConfig(), ["view.live=true", "actor.num_actors=2"])
    started = [spec.role for spec in plan_children(config)]
    assert started == ["replay", "live", "clusterer", "learner", "evaluator", "actor", "actor"]
    assert STOP_STAGES[0] == ("actor",) and STOP_STAGES[-1] == ("replay",)
    assert sorted(r for stage in STOP_STAGES for r in stage) == sorted(ROLES)
    assert "live" not in [s.role for s in plan_children(HercsConfig())]
    assert {"live"} == OPTIONAL_ROLES


def test_every_role_has_its_grants() -> None:
    assert set(ROLE_GRANTS) == set(ROLES)


def test_a_run_whose_learner_is_elsewhere_starts_none() -> None:
    config = apply_overrides(HercsConfig(), ["launch.learner_elsewhere=true"])
    assert [s.role for s in plan_children(config)] == ["replay", "clusterer", "evaluator",
                                                       "actor"]
