"""The env factory: no third-party notice on stderr, rendering that changes nothing."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from hercs.envs import make_env
from hercs.tasks import task_spec


def test_making_an_env_prints_nothing() -> None:
    """gymnasium-robotics 1.4.2 prints an Adroit notice on import; hercs drops it."""
    done = subprocess.run(
        [sys.executable, "-c", "from hercs.envs import make_env; from hercs.tasks import "
         "task_spec; make_env(task_spec('push')).close()"],
        capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stderr == "" and done.stdout == ""


def test_a_reset_draws_the_same_goals_with_or_without_rendering() -> None:
    spec = task_spec("push")
    plain, rendered = make_env(spec), make_env(spec, render_mode="rgb_array", size=(64, 48))
    try:
        for seed in (3, None, None):
            a, _ = plain.reset(seed=seed)
            b, _ = rendered.reset(seed=seed)
            np.testing.assert_array_equal(a["desired_goal"], b["desired_goal"])
            np.testing.assert_array_equal(a["observation"], b["observation"])
    finally:
        plain.close()
        rendered.close()
