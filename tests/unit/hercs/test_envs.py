"""The env factory: no third-party notice on stderr, rendering that changes nothing, v4 whether
or not mujoco-py is set up, v1 refused with what to run where it is not."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from hercs.rl.envs import make_env
from hercs.rl.task_registry import task_spec
from tests.support import skip_without_mujoco_py


@pytest.mark.parametrize("version", ["v4", "v1"])
def test_making_an_env_prints_nothing(version: str) -> None:
    """gymnasium-robotics 1.4.2 prints an Adroit notice on import, and warns that v1 is out of
    date and mujoco-py unmaintained; hercs drops them. The v4 case holds with or without
    mujoco-py installed (gymnasium-robotics then imports it for v4 too)."""
    if version == "v1":
        skip_without_mujoco_py()
    done = subprocess.run(
        [sys.executable, "-W", "default", "-c", "from hercs.rl.envs import make_env; from "
         f"hercs.rl.task_registry import task_spec; "
         f"make_env(task_spec('push', {version!r})).close()"],
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
    code = ("from hercs.rl.envs import make_env; from hercs.errors import ConfigError; "
            "from hercs.rl.task_registry import task_spec\n"
            "make_env(task_spec('push')).close()\n"
            "try:\n    make_env(task_spec('push', 'v1'))\n"
            "except ConfigError as exc:\n    print(exc)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "MUJOCO_PY_MUJOCO_PATH": str(tmp_path)})
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("task.env_version: got 'v1', but FetchPush-v1 runs on "
                                  "mujoco-py (MuJoCo 2.1) and "), done.stdout
    assert "`make mujoco-py`" in done.stdout and done.stderr == ""


PREPARE = """
import os, sys
from hercs.rl import envs
print(envs.prepare_mujoco_py())
print(os.environ.get("LD_LIBRARY_PATH", ""), os.environ.get("MUJOCO_PY_MUJOCO_PATH", ""))
"""


def test_an_extension_compiled_again_since_make_mujoco_py_is_refused_not_recompiled(
        tmp_path) -> None:
    """mujoco-py drops the extension's RUNPATH whenever it compiles it, after which it loads
    only where LD_LIBRARY_PATH listed MuJoCo 2.1's bin/ at process start, and mujoco-py would
    compile it again in every process that imports it. So hercs uses a compiled extension only
    with `make mujoco-py`'s mark newer than it, or that LD_LIBRARY_PATH (a stand-in package)."""
    generated = tmp_path / "site" / "mujoco_py" / "generated"
    generated.mkdir(parents=True)
    (generated.parent / "__init__.py").write_text("raise SystemExit('imported')\n")
    built = generated / "cymj_2.1.2.15_311_linuxcpuextensionbuilder_311.so"
    built.write_bytes(b"")
    bin_dir = tmp_path / "mujoco210" / "bin"
    bin_dir.mkdir(parents=True)
    (bin_dir / "libmujoco210.so").write_bytes(b"")
    mark = generated / "hercs-runpath"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "site"), *sys.path]),
           "MUJOCO_PY_MUJOCO_PATH": str(bin_dir.parent), "LD_LIBRARY_PATH": ""}

    def prepare(**extra: str) -> list[str]:
        done = subprocess.run([sys.executable, "-c", PREPARE], capture_output=True, text=True,
                              timeout=60, env={**env, **extra})
        assert done.returncode == 0, done.stderr
        return done.stdout.splitlines()

    assert prepare()[0].startswith(f"mujoco-py's extension in {generated} was compiled "
                                   f"without the RUNPATH that finds {bin_dir}")
    mark.write_text(f"{bin_dir}\n")  # what make mujoco-py writes after patchelf
    assert prepare() == ["None", f"{bin_dir} {bin_dir.parent}"]
    os.utime(built, (mark.stat().st_mtime + 5,) * 2)  # compiled again since
    assert prepare()[0].startswith("mujoco-py's extension")
    assert prepare(LD_LIBRARY_PATH=str(bin_dir))[0] == "None"  # the loader finds bin/ anyway
    built.unlink()
    assert prepare()[0] == f"mujoco-py's extension is not compiled (none in {generated})"


def test_the_weld_torquescale_setting_reaches_the_v4_model() -> None:
    """The mocap weld of a real FetchPush-v4 gets `task.weld_torquescale` (MuJoCo 3's default
    1 otherwise), and keeps it across resets."""
    import dataclasses

    from hercs.rl.envs import WELD_TORQUESCALE, make_env
    from hercs.rl.task_registry import task_spec

    plain = make_env(task_spec("push"))
    stiff = make_env(dataclasses.replace(task_spec("push"), weld_torquescale=4.0))
    try:
        stiff.reset(seed=0)
        stiff.reset(seed=1)
        assert plain.unwrapped.model.eq_data[:, WELD_TORQUESCALE].tolist() == [1.0]
        assert stiff.unwrapped.model.eq_data[:, WELD_TORQUESCALE].tolist() == [4.0]
    finally:
        plain.close()
        stiff.close()
