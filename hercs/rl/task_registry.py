"""Which task a name means: `task_spec(task.name, …)` → `TaskSpec` (hercs.rl.task_spec).

A built-in name or gymnasium id (`BUILT_IN`: Fetch, PointMaze, HandReach, HandManipulate) has
its spec written here and tested against the real env; any other id or `module:factory` has
its spec read from the env (hercs.rl.goal_env). Each Fetch task has a `-v4` (MuJoCo 3, the
default) and the authors' `-v1` (mujoco-py) version (`ENV_VERSIONS`, docs/DESIGN.md §9.6).
"""

from __future__ import annotations

import dataclasses
import re

from hercs.errors import ConfigError
from hercs.rl.task_spec import (
    ENERGIES,
    ENV_VERSIONS,
    FACTORY,
    REWARD_RULES,
    EnvRule,
    TaskSpec,
    env_rule,
    fetch_reward,
    goal_distance,
    hand_success,
)

__all__ = ["BUILT_IN", "ENERGIES", "ENV_VERSIONS", "FACTORY", "REWARD_RULES", "TASKS", "EnvRule",
           "TaskSpec", "env_rule", "fetch_reward", "goal_distance", "hand_success", "task_spec"]

TASKS: dict[str, TaskSpec] = {
    "reach": TaskSpec(name="reach", env_name="FetchReach", obs_dim=10, has_object=False),
    "push": TaskSpec(name="push", env_name="FetchPush", obs_dim=25),
    "pick": TaskSpec(name="pick", env_name="FetchPickAndPlace", obs_dim=25),
    "slide": TaskSpec(name="slide", env_name="FetchSlide", obs_dim=25),
}
"""The Fetch tasks on the default environment version (v4), by short name."""

FETCH_ID = re.compile(r"(Fetch(?:Reach|Push|PickAndPlace|Slide))-(v\d+)")
POINTMAZE_ID = re.compile(r"PointMaze_\w+-v3")
HAND_REACH_ID = re.compile(r"HandReach-v3")
HAND_MANIPULATE_ID = re.compile(r"HandManipulate(Block|Egg|Pen)(Rotate\w*|Full)?-v1")
HAND_THRESHOLDS = {"Block": 0.01, "Egg": 0.01, "Pen": 0.05}
"""The hand manipulation tasks' position thresholds (their rotation threshold is 0.1 rad)."""

BUILT_IN: tuple[str, ...] = ("reach", "push", "pick", "slide", "Fetch{Reach,Push,PickAndPlace,"
                             "Slide}-v4|v1", "PointMaze_*-v3", "HandReach-v3",
                             "HandManipulate{Block,Egg,Pen}*-v1")
"""What `task.name` accepts with a spec written here (any other goal env is read from it)."""



def task_spec(name: str, env_version: str = "v4", weld_torquescale: float = 1.0,
              episode_steps: int = 0) -> TaskSpec:
    """The spec of `task.name` (with `episode_steps` > 0: made with that horizon); a name with
    no spec here is read from its environment (made once per process:
    `hercs.rl.goal_env.inspect_goal_env`), which raises ConfigError saying what is missing where
    it is not a goal environment."""
    spec = _task_spec(name, env_version, weld_torquescale)
    if episode_steps <= 0 or episode_steps == spec.episode_steps:
        return spec
    return dataclasses.replace(spec, episode_steps=episode_steps, make_kwargs=(
        *spec.make_kwargs, ("max_episode_steps", episode_steps)))


def _task_spec(name: str, env_version: str, weld_torquescale: float) -> TaskSpec:
    if env_version not in ENV_VERSIONS:
        raise ConfigError(f"task.env_version: got {env_version!r}, must be one of "
                          f"{list(ENV_VERSIONS)}")
    fetch = FETCH_ID.fullmatch(name)
    if fetch is not None:
        short = next(k for k, s in TASKS.items() if s.env_name == fetch.group(1))
        if fetch.group(2) not in ENV_VERSIONS:
            raise ConfigError(f"task.name: got {name!r}; hercs runs {fetch.group(1)} in "
                              f"versions {list(ENV_VERSIONS)}")
        return dataclasses.replace(TASKS[short], name=name, env_version=fetch.group(2),
                                   weld_torquescale=weld_torquescale)
    if name in TASKS:
        return dataclasses.replace(TASKS[name], env_version=env_version,
                                   weld_torquescale=weld_torquescale)
    if weld_torquescale != 1.0:
        raise ConfigError(f"task.weld_torquescale: got {weld_torquescale}; only the Fetch "
                          f"tasks have a gripper weld, {name!r} is not one")
    built_in = _built_in(name)
    if built_in is not None:
        return built_in
    if not (FACTORY.fullmatch(name) or re.fullmatch(r"[\w./:-]+-v\d+", name)):
        raise ConfigError(f"task.name: got {name!r}; expected one of {sorted(TASKS)}, a "
                          "gymnasium id of a goal environment (e.g. PointMaze_UMaze-v3) or "
                          "package.module:factory")
    from hercs.rl.code_names import check_may_import
    from hercs.rl.goal_env import inspect_goal_env

    check_may_import(name)  # before anything is imported for it
    return inspect_goal_env(name)


def _built_in(name: str) -> TaskSpec | None:
    from hercs.rl.goal_env import registered_steps

    if POINTMAZE_ID.fullmatch(name):
        # T is the registry's (UMaze 300 … Large 800): read without making the env
        return TaskSpec(name=name, env_name=name, family="pointmaze", obs_dim=4, goal_dim=2,
                        action_dim=2, episode_steps=registered_steps(name),
                        distance_threshold=0.45, threshold_inclusive=True, success_reward=1.0,
                        failure_reward=0.0, success_key="success", energy="none",
                        has_object=False, gripper_position=False)
    if HAND_REACH_ID.fullmatch(name):
        return TaskSpec(name=name, env_name=name, family="hand_reach", obs_dim=63,
                        goal_dim=15, action_dim=20, episode_steps=50, distance_threshold=0.01,
                        has_object=False, gripper_position=False)
    hand = HAND_MANIPULATE_ID.fullmatch(name)
    if hand is not None:
        from hercs.rl.goal_env import registered_kwargs

        kwargs = registered_kwargs(name)
        return TaskSpec(name=name, env_name=name, family="hand_manipulate", obs_dim=61,
                        goal_dim=7, action_dim=20, episode_steps=registered_steps(name),
                        distance_threshold=HAND_THRESHOLDS[hand.group(1)], reward_rule="hand",
                        target_position=kwargs.get("target_position", "random"),
                        target_rotation=kwargs.get("target_rotation", "xyz"),
                        ignore_z_rotation=hand.group(1) == "Pen", energy="hand",
                        has_object=False, gripper_position=False)
    return None


