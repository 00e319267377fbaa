"""Environment factory: gymnasium-robotics Fetch tasks, seeded, without the env checker."""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym

from hercs.tasks import TaskSpec

_registered = False


def _drop_adroit_notice() -> None:
    """gymnasium-robotics 1.4.2 prints, on import, a notice about the Adroit hand tasks'
    rewards (from the `farama_notifications` table) to every process's stderr; hercs uses only
    the Fetch tasks, so the entry is removed before the import reads it."""
    try:
        import farama_notifications
    except ImportError:
        return
    farama_notifications.notifications.pop("gymnasium_robotics", None)


def make_env(spec: TaskSpec, *, render_mode: str | None = None,
             size: tuple[int, int] | None = None) -> gym.Env:
    """A fresh Fetch env for `spec`. Seed it through the first `reset(seed=...)`. With
    `render_mode='rgb_array'`, `render()` returns frames of `size` (width, height); rendering
    does not change the dynamics or the env's random stream."""
    global _registered
    if not _registered:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _drop_adroit_notice()
            import gymnasium_robotics

            gym.register_envs(gymnasium_robotics)
        _registered = True
    # The passive env checker only re-validates spaces on every step; it costs throughput.
    kwargs: dict[str, Any] = {}
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    if size is not None:
        kwargs["width"], kwargs["height"] = size
    return gym.make(spec.env_id, disable_env_checker=True, **kwargs)
