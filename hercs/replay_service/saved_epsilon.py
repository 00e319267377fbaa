"""`saved_epsilon`: the config a replay serves, with a run's own ε kept across a resume and a
changed default."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

from hercs.config import HercsConfig, load_yaml
from hercs.errors import ConfigError

log = logging.getLogger("hercs.replay")


def saved_epsilon(config: HercsConfig, saved: Path) -> HercsConfig:
    """`config` with the ε written out: where it leaves ε unset and the run saved a config
    with a number, that number (a compose run resumed with HERCS_RESUME rebuilds its config
    from flags, and a run made before v4's default ε changed must keep its own), else its
    environment's default. The services get it from here (`join_run`)."""
    if config.energy.epsilon is None and saved.is_file():
        try:
            epsilon = load_yaml(saved).energy_epsilon
        except (ConfigError, OSError) as exc:
            log.warning("%s: not read for its energy.epsilon (%s); using the default", saved,
                        exc)
        else:
            return replace(config, energy=replace(config.energy, epsilon=epsilon))
    return config.resolved()
