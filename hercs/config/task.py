"""The `task` section of the configuration tree (hercs.config re-exports it)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from hercs.config.checks import _check
from hercs.rl.task_registry import ENV_VERSIONS, TASKS, TaskSpec, task_spec


@dataclass
class TaskConfig:
    name: str = "push"
    """The task: a Fetch preset (reach, push, pick = PickAndPlace, slide), a gymnasium id of
    a goal environment (PointMaze_UMaze-v3, HandReach-v3, …; hercs.rl.task_registry.BUILT_IN have
    specs written and tested here, any other is read from the env), or package.module:factory
    for a user's own environment (docs/DESIGN.md §4.9)."""
    env_version: str = "v4"
    """v4: gymnasium-robotics Fetch*-v4 on MuJoCo 3 [DESIGN]; v1: the authors' Fetch*-v1 on
    mujoco-py and MuJoCo 2.1 [HER-py] (installed by `make mujoco-py`). Same shapes, horizon
    and reward; the physics differ (docs/DESIGN.md §9)."""
    weld_torquescale: float = 1.0
    """v4 only: the torquescale of the mocap weld that moves the gripper, MuJoCo 3's
    rotational weight of the weld (1, its default). MuJoCo 2.1 has no such setting and holds
    the gripper ~10x stiffer against tilting; 4 makes v4's gripper tilt, and the pushed cube
    turn and topple, as on v1 (docs/results/env_diff.md) [DESIGN]."""
    episode_steps: int = 0
    """Steps per episode: 0 keeps the task's own horizon (Fetch 50 [HER-py]; PointMaze and
    other envs their registry's); n makes the env with max_episode_steps=n [DESIGN]."""
    indexed_reads: bool = True
    """A gymnasium-robotics MuJoCo env (Fetch v4, the Shadow hand envs) reads its observation
    by joint and site ids resolved once instead of by name each step: bit-identical, ~1.3x
    cheaper steps (hercs/rl/indexed_lookups.py, docs/PERFORMANCE.md §3). false: by name, as
    gymnasium-robotics does (the comparison's baseline)."""

    def __post_init__(self) -> None:
        _check(bool(self.name.strip()), "task.name", self.name,
               f"name a task: one of {sorted(TASKS)}, a gymnasium id or module:factory")
        _check(self.env_version in ENV_VERSIONS, "task.env_version", self.env_version,
               f"be one of {list(ENV_VERSIONS)} (v1 is the authors' Fetch*-v1 on mujoco-py)")
        _check(math.isfinite(self.weld_torquescale) and self.weld_torquescale > 0,
               "task.weld_torquescale", self.weld_torquescale, "be a finite number > 0")
        _check(self.episode_steps >= 0, "task.episode_steps", self.episode_steps,
               "be >= 0 (0: the task's own horizon)")
        _check(self.weld_torquescale == 1.0 or self.env_version == "v4",
               "task.weld_torquescale", self.weld_torquescale,
               "be 1 with task.env_version v1 (MuJoCo 2.1's weld has no torquescale)")

    @property
    def spec(self) -> TaskSpec:
        """The task on its environment version: what every env factory makes."""
        spec = task_spec(self.name, self.env_version, self.weld_torquescale,
                         self.episode_steps)
        return spec if self.indexed_reads else dataclasses.replace(spec, indexed_reads=False)
