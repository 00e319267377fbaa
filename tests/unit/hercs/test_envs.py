"""The env factory: no third-party notice on stderr, rendering that changes nothing, v4 whether
or not mujoco-py is set up, v1 refused with what to run where it is not."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from hercs.envs import make_env
from hercs.tasks import task_spec
from tests.support import skip_without_mujoco_py


@pytest.mark.parametrize("version", ["v4", "v1"])
def test_making_an_env_prints_nothing(version: str) -> None:
    """gymnasium-robotics 1.4.2 prints an Adroit notice on import, and warns that v1 is out of
    date and mujoco-py unmaintained; hercs drops them. The v4 case holds with or without
    mujoco-py installed (gymnasium-robotics then imports it for v4 too)."""
    if version == "v1":
        skip_without_mujoco_py()
    done = subprocess.run(
        [sys.executable, "-W", "default", "-c", "from hercs.envs import make_env; from "
         f"hercs.tasks import task_spec; make_env(task_spec('push', {version!r})).close()"],
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


def test_without_mujoco_2_1_v4_still_works_and_v1_says_how_to_install_it(tmp_path) -> None:
    """MuJoCo 2.1 missing (MUJOCO_PY_MUJOCO_PATH names an empty folder): where mujoco-py is
    installed, gymnasium-robotics imports it with every Fetch env and its import would raise;
    hercs makes it an ImportError, so v4 works, and a v1 env is refused with what to run."""
    code = ("from hercs.envs import make_env; from hercs.errors import ConfigError; "
            "from hercs.tasks import task_spec\n"
            "make_env(task_spec('push')).close()\n"
            "try:\n    make_env(task_spec('push', 'v1'))\n"
            "except ConfigError as exc:\n    print(exc)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "MUJOCO_PY_MUJOCO_PATH": str(tmp_path)})
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("task.env_version: got 'v1', but FetchPush-v1 runs on "
                                  "mujoco-py (MuJoCo 2.1) and "), done.stdout
    assert "`make mujoco-py`" in done.stdout and done.stderr == ""
