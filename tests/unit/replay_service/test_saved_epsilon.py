"""The config a replay serves its run's services: energy.epsilon written out (docs/DESIGN.md
§9.3), from the run's saved config where the replay's own leaves it unset."""

from __future__ import annotations

from pathlib import Path

from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.replay_service.builder import saved_epsilon


def test_an_unset_epsilon_is_the_saved_runs_else_the_environments(tmp_path: Path) -> None:
    saved = tmp_path / "config.yaml"
    # no saved config: the environment's default
    assert saved_epsilon(HercsConfig(), saved).energy.epsilon == 1e-3
    v1 = apply_overrides(HercsConfig(), ["task.env_version=v1"])
    assert saved_epsilon(v1, saved).energy.epsilon == 1e-6
    # a run made with 1e-6 on v4 (before the default changed), resumed by a compose replay
    # whose flags leave ε unset, keeps its 1e-6
    save_yaml(apply_overrides(HercsConfig(), ["energy.epsilon=1e-6"]), saved)
    assert saved_epsilon(HercsConfig(), saved).energy.epsilon == 1e-6
    # a number given to the replay itself wins
    given = apply_overrides(HercsConfig(), ["energy.epsilon=2e-4"])
    assert saved_epsilon(given, saved).energy.epsilon == 2e-4
    # an unreadable saved config is passed over for the default, not a crash
    saved.write_text("energy: [not, a, mapping\n")
    assert saved_epsilon(HercsConfig(), saved).energy.epsilon == 1e-3
