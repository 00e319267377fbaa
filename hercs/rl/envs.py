"""Environment factory: gymnasium-robotics tasks (or a user's module:factory), seeded, without
the env checker.

`Fetch*-v4` runs on MuJoCo 3; the authors' `Fetch*-v1` on mujoco-py and MuJoCo 2.1 (`make
mujoco-py`: MuJoCo 2.1's binaries in `<venv>/mujoco210`, and mujoco-py's Cython extension
compiled with that folder's `bin/` as its RUNPATH, so no process needs LD_LIBRARY_PATH at its
start). `prepare_mujoco_py` sets what mujoco-py reads at import, in every process that makes an
env; `check_env` says at a run's start when that installation is missing.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from hercs.errors import ConfigError
from hercs.rl.indexed_lookups import index_lookups
from hercs.rl.task_spec import FACTORY, TaskSpec

MUJOCO210 = Path(sys.prefix) / "mujoco210"
"""Where `make mujoco-py` puts MuJoCo 2.1 (inside the virtualenv)."""
RUNPATH_MARK = "hercs-runpath"
"""The file, beside mujoco-py's compiled extension, where `make mujoco-py` notes the RUNPATH
it gave the extension."""
INSTALL_HINT = ("`make mujoco-py` in the hercs checkout installs it (docs/results/README.md, "
                "\"The authors' environment\")")

_registered = False
_blocked: str | None = None
"""Why `prepare_mujoco_py` made `import mujoco_py` fail in this process, if it did."""


def _drop_adroit_notice() -> None:
    """gymnasium-robotics 1.4.2 prints, on import, a notice about the Adroit hand tasks'
    rewards (from the `farama_notifications` table) to every process's stderr; hercs uses only
    the Fetch tasks, so the entry is removed before the import reads it."""
    try:
        import farama_notifications
    except ImportError:
        return
    farama_notifications.notifications.pop("gymnasium_robotics", None)


def prepare_mujoco_py() -> str | None:
    """Point mujoco-py at MuJoCo 2.1 before anything imports it; returns why it cannot be
    imported here, or None when it can.

    Once mujoco-py is installed, gymnasium-robotics imports it with every Fetch env, v4
    included, and the import raises (a bare Exception, which gymnasium-robotics lets through)
    unless MUJOCO_PY_MUJOCO_PATH names MuJoCo 2.1 and LD_LIBRARY_PATH lists its `bin/`; where
    its extension is not compiled, or does not load, it compiles it (again) first. So, in this
    process's environment (children inherit it): MUJOCO_PY_MUJOCO_PATH defaults to MUJOCO210;
    its `bin/` is appended to LD_LIBRARY_PATH (mujoco-py only checks the variable: the loader
    reads it at process start only, and the extension finds the libraries through the RUNPATH
    `make mujoco-py` gave it); MUJOCO_PY_FORCE_CPU defaults to 1, the OSMesa build `make
    mujoco-py` compiled (where `nvidia-smi` exists mujoco-py would build for EGL). Where MuJoCo
    2.1 is missing, or the extension is not compiled, or was compiled again since `make
    mujoco-py` set its RUNPATH (a compile drops it) and LD_LIBRARY_PATH did not list `bin/`
    when this process started, `import mujoco_py` is made to raise ImportError instead: the v4
    envs work and never wait for a compile."""
    global _blocked
    if "mujoco_py" in sys.modules:  # imported, or blocked, earlier in this process
        return _blocked
    package = importlib.util.find_spec("mujoco_py")
    if package is None or not package.submodule_search_locations:
        return "mujoco_py is not installed"
    path = Path(os.environ.get("MUJOCO_PY_MUJOCO_PATH") or MUJOCO210).absolute()
    bin_dir = str(path / "bin")
    generated = Path(package.submodule_search_locations[0]) / "generated"
    built = list(generated.glob("cymj_*_linuxcpuextensionbuilder_*.so"))
    paths = [p for p in os.environ.get("LD_LIBRARY_PATH", "").split(":") if p]
    on_path = bin_dir in (os.path.abspath(p) for p in paths)
    if not (path / "bin" / "libmujoco210.so").is_file():
        _blocked = f"MuJoCo 2.1 is not in {path}"
    elif not built:
        _blocked = f"mujoco-py's extension is not compiled (none in {generated})"
    elif not on_path and not _runpath_set(generated, built, bin_dir):
        _blocked = (f"mujoco-py's extension in {generated} was compiled without the RUNPATH "
                    f"that finds {bin_dir}")
    if _blocked is not None:
        sys.modules["mujoco_py"] = None  # type: ignore[assignment]
        return _blocked
    os.environ["MUJOCO_PY_MUJOCO_PATH"] = str(path)
    if not on_path:
        os.environ["LD_LIBRARY_PATH"] = ":".join([*paths, bin_dir])
    os.environ.setdefault("MUJOCO_PY_FORCE_CPU", "1")
    return None


def _runpath_set(generated: Path, built: list[Path], bin_dir: str) -> bool:
    """Whether `make mujoco-py` gave the compiled extension `bin_dir` as RUNPATH since its last
    compile: it writes `bin_dir` to RUNPATH_MARK after patchelf, and a compile writes a newer
    extension."""
    mark = generated / RUNPATH_MARK
    try:
        return (mark.read_text().strip() == bin_dir
                and mark.stat().st_mtime >= max(so.stat().st_mtime for so in built))
    except OSError:
        return False


def mujoco_py_problem() -> str | None:
    """Why the v1 envs cannot be made in this process, or None. Imports mujoco_py; where that
    fails, blocks it as `prepare_mujoco_py` does (the v4 envs still work)."""
    global _blocked
    problem = prepare_mujoco_py()
    if problem is None and "mujoco_py" not in sys.modules:
        try:
            with warnings.catch_warnings():  # Cython's and importlib's deprecations
                warnings.simplefilter("ignore")
                import mujoco_py  # noqa: F401
        except Exception as exc:  # mujoco_py raises bare Exceptions for a broken set-up
            last = (str(exc).strip().splitlines() or [type(exc).__name__])[-1]
            problem = _blocked = f"importing mujoco_py failed ({last})"
            sys.modules["mujoco_py"] = None  # type: ignore[assignment]
    return problem


def check_env(spec: TaskSpec) -> None:
    """Raise ConfigError, saying how to install what is missing, where `spec`'s env cannot be
    made here (the v1 envs without mujoco-py); what a run checks before it starts."""
    if spec.env_version != "v1":
        return
    problem = mujoco_py_problem()
    if problem is not None:
        raise ConfigError(f"task.env_version: got 'v1', but {spec.env_id} runs on mujoco-py "
                          f"(MuJoCo 2.1) and {problem}; {INSTALL_HINT}")


def register_envs() -> None:
    """Register gymnasium-robotics' environments in this process (once), quietly."""
    global _registered
    if not _registered:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _drop_adroit_notice()
            mujoco_py_problem()  # gymnasium-robotics imports mujoco_py: here, quietly
            import gymnasium_robotics

            gym.register_envs(gymnasium_robotics)
        _registered = True


def make_env(spec: TaskSpec, *, render_mode: str | None = None,
             size: tuple[int, int] | None = None, camera: Mapping[str, Any] | None = None,
             indexed: bool | None = None) -> gym.Env:
    """A fresh env for `spec` (its `env_id`, or its module:factory). Seed it through the
    first `reset(seed=...)`. With `render_mode='rgb_array'`, `render()` returns frames of
    `size` (width, height) seen by its free camera, placed by `camera` where given (the
    `default_camera_config` of a gymnasium-robotics MuJoCo env: distance, azimuth,
    elevation, lookat); rendering does not change the dynamics or the env's random
    stream. A gymnasium-robotics MuJoCo env reads its observation by ids resolved once
    (`indexed`, by default `spec.indexed_reads`; bit-identical: hercs/rl/indexed_lookups.py).
    A v1 env where mujoco-py is not installed raises ConfigError (`check_env`)."""
    register_envs()
    check_env(spec)
    # The passive env checker only re-validates spaces on every step; it costs throughput.
    kwargs: dict[str, Any] = dict(spec.make_kwargs)
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    if size is not None:
        kwargs["width"], kwargs["height"] = size
    if camera is not None:
        kwargs["default_camera_config"] = {k: np.asarray(v) if isinstance(v, tuple | list)
                                           else v for k, v in camera.items()}
    if FACTORY.fullmatch(spec.env_id):
        steps = kwargs.pop("max_episode_steps", None)
        env = make_from_factory(spec.env_id, kwargs)
        # a factory takes its own arguments: the horizon is a TimeLimit around what it made
        return env if steps is None else gym.wrappers.TimeLimit(env, max_episode_steps=steps)
    with warnings.catch_warnings():
        # v1 was chosen knowingly: not "out of date, upgrade to v4" and "mujoco-py is no
        # longer maintained" on every process's stderr.
        warnings.filterwarnings("ignore", message=".*(is out of date|mujoco-py bindings)")
        try:
            env = gym.make(spec.env_id, disable_env_checker=True, **kwargs)
        except gym.error.Error as exc:
            raise ConfigError(f"task.name: gymnasium cannot make {spec.env_id!r} here "
                              f"({exc}); is the package that registers it installed and "
                              "imported? A user's own environment can be named "
                              "package.module:factory") from None
    if spec.weld_torquescale != 1.0:
        set_weld_torquescale(env, spec.weld_torquescale)
    use_indexed = spec.indexed_reads if indexed is None else indexed
    if use_indexed:
        index_lookups(env)
    return env


def make_from_factory(target: str, kwargs: dict[str, Any]) -> gym.Env:
    """`package.module:factory` called with `kwargs` (render_mode, width, height where asked):
    a user's own environment. Its package must be importable in every process that makes it
    (the actors, the evaluator, and the replay and clusterer for its reward)."""
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(
            f"task.name: cannot import {module_name!r} for {target!r} ({exc}); the package "
            "that defines the environment must be importable in every process of the run "
            "(install it in this environment, or add it to PYTHONPATH; on remote actor hosts "
            "and in compose images too)") from None
    factory = getattr(module, attr, None)
    if not callable(factory):
        raise ConfigError(f"task.name: {module_name} has no callable {attr!r} (from {target!r})")
    env = factory(**kwargs)
    if not isinstance(env, gym.Env):
        raise ConfigError(f"task.name: {target}() returned {type(env).__name__}, not a "
                          "gymnasium.Env")
    return env


WELD_TORQUESCALE = 10
"""Index of a weld's torquescale in MuJoCo 3's `eq_data` row (anchor 0:3, relpose 3:10)."""


def set_weld_torquescale(env: gym.Env, value: float) -> None:
    """Set the torquescale of every weld of a v4 env's model (the Fetch tasks have one: the
    mocap weld that drives the gripper). Takes effect from the next step; a reset keeps it
    (the model is not reloaded)."""
    import mujoco  # type: ignore[import-untyped]

    model = env.unwrapped.model  # type: ignore[attr-defined]
    welds = model.eq_type == mujoco.mjtEq.mjEQ_WELD
    if not welds.any():
        raise ConfigError(f"task.weld_torquescale: {env.spec.id if env.spec else env} has no "
                          "weld to set")
    model.eq_data[welds, WELD_TORQUESCALE] = value
