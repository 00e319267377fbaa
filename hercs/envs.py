"""Environment factory: gymnasium-robotics Fetch tasks, seeded, without the env checker."""

from __future__ import annotations

import warnings

import gymnasium as gym

from hercs.tasks import TaskSpec

_registered = False


def make_env(spec: TaskSpec) -> gym.Env:
    """A fresh Fetch env for `spec`. Seed it through the first `reset(seed=...)`."""
    global _registered
    if not _registered:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import gymnasium_robotics

            gym.register_envs(gymnasium_robotics)
        _registered = True
    # The passive env checker only re-validates spaces on every step; it costs throughput.
    return gym.make(spec.env_id, disable_env_checker=True)
