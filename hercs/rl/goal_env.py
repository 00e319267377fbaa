"""Any goal-conditioned environment as a hercs task: its spec read from the environment, its
reward and success rule from the environment's own functions.

`inspect_goal_env` checks the goal interface HER needs (docs/DESIGN.md §4.9) and names what is
missing in a `ConfigError`, so `hercs up` exits 2 before any service starts. The reward
functions are an env instance's (`env_rule`), one per process that needs them, never stepped.
"""

from __future__ import annotations

import functools
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

from hercs.errors import ConfigError
from hercs.rl.envs import make_env, register_envs
from hercs.rl.task_spec import EnvRule, TaskSpec, set_env_rule_maker

GOAL_KEYS = ("observation", "achieved_goal", "desired_goal")


def registered_steps(env_id: str) -> int:
    """`max_episode_steps` of a registered id, without making the env."""
    register_envs()
    try:
        steps = gym.spec(env_id).max_episode_steps
    except gym.error.Error as exc:
        raise ConfigError(f"task.name: {env_id!r} is not a registered gymnasium id ({exc})") \
            from None
    if not steps:
        raise ConfigError(f"task.name: {env_id} has no max_episode_steps in the registry")
    return int(steps)


def registered_kwargs(env_id: str) -> dict[str, Any]:
    """The keyword arguments a registered id makes its env with."""
    register_envs()
    return dict(gym.spec(env_id).kwargs)


def _problems(env: gym.Env) -> tuple[list[str], dict[str, Any]]:
    """What `env` lacks of the goal interface, and what was read from it."""
    problems: list[str] = []
    found: dict[str, Any] = {}
    space = env.observation_space
    if not isinstance(space, gym.spaces.Dict) or not all(k in space.spaces for k in GOAL_KEYS):
        keys = list(space.spaces) if isinstance(space, gym.spaces.Dict) else type(space).__name__
        problems.append(f"a dict observation space with keys {list(GOAL_KEYS)} (it has "
                        f"{keys})")
    else:
        shapes = {k: space.spaces[k].shape for k in GOAL_KEYS}
        if any(shape is None or len(shape) != 1 for shape in shapes.values()):
            problems.append(f"1-d observation, achieved_goal and desired_goal (shapes {shapes})")
        elif shapes["achieved_goal"] != shapes["desired_goal"]:
            problems.append(f"achieved_goal and desired_goal of one size ({shapes})")
        else:
            found["obs_dim"] = int(shapes["observation"][0])  # type: ignore[index]
            found["goal_dim"] = int(shapes["desired_goal"][0])  # type: ignore[index]
    action = env.action_space
    if not isinstance(action, gym.spaces.Box) or len(action.shape) != 1:
        problems.append(f"a 1-d Box action space (it has {action})")
    else:
        high = np.asarray(action.high, np.float64)
        low = np.asarray(action.low, np.float64)
        if not (np.all(np.isfinite(high)) and np.allclose(-low, high)
                and np.allclose(high, high[0])):
            problems.append("an action space symmetric about 0 with one bound for every "
                            f"dimension (low {low.tolist()}, high {high.tolist()})")
        else:
            found["action_dim"], found["max_action"] = int(action.shape[0]), float(high[0])
    steps = (env.spec.max_episode_steps if env.spec is not None else None) \
        or getattr(env, "_max_episode_steps", None)
    if not steps:
        problems.append("a fixed horizon: max_episode_steps in its registration, or a "
                        "gymnasium.wrappers.TimeLimit around it")
    else:
        found["episode_steps"] = int(steps)
    if not callable(getattr(env.unwrapped, "compute_reward", None)):
        problems.append("compute_reward(achieved_goal, desired_goal, info)")
    return problems, found


@functools.cache
def inspect_goal_env(name: str) -> TaskSpec:
    """The spec of the environment `name` (a gymnasium id or module:factory), read from one
    instance that is reset once; ConfigError listing what it lacks of the goal interface."""
    probe = TaskSpec(name=name, env_name=name, obs_dim=1, family="custom", reward_rule="env",
                     energy="none", has_object=False, gripper_position=False)
    env = make_env(probe)
    try:
        problems, found = _problems(env)
        if not problems:
            obs, _ = env.reset(seed=0)
            g = np.asarray(obs["desired_goal"], np.float64)
            action = np.zeros(found["action_dim"], np.float32)
            *_, info = env.step(action)
            if "is_success" not in info:
                problems.append(f'info["is_success"] on every step (a step\'s info has '
                                f"{sorted(info)})")
            # the rewards of a goal reached exactly and of one missed far away: the range the
            # learner clips its TD targets to (sparse rewards, the setting HER is for)
            far = g + 1e3 * (1.0 + np.abs(g))
            batch = _batched_reward(env, np.stack([g, far]), np.stack([g, g]))
            if batch is None:
                problems.append("compute_reward that works on batches: (2, goal_dim) goals "
                                "must give 2 rewards")
            else:
                found["success_reward"], found["failure_reward"] = (float(v) for v in batch)
    finally:
        env.close()
    if problems:
        raise ConfigError(f"task.name: {name} is not a goal environment hercs can train on; "
                          "it lacks " + "; ".join(problems) + " (docs/DESIGN.md §4.9)")
    return TaskSpec(name=name, env_name=name, family="custom", reward_rule="env",
                    energy="none", has_object=False, gripper_position=False,
                    distance_threshold=float(getattr(env.unwrapped, "distance_threshold", 0.0)),
                    **found)


def _batched_reward(env: gym.Env, ag: np.ndarray, g: np.ndarray) -> np.ndarray | None:
    """The env's rewards of a batch of goal pairs, or None where it does not take batches."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = np.asarray(env.unwrapped.compute_reward(ag, g, {}),  # type: ignore[attr-defined]
                           np.float64)
    except Exception:  # a reward written for one pair raises anything on a batch
        return None
    return r if r.shape == (len(ag),) and np.all(np.isfinite(r)) else None


def make_env_rule(spec: TaskSpec) -> EnvRule:
    """The reward and success functions of one instance of `spec`'s env, never stepped."""
    env = make_env(spec)
    unwrapped = env.unwrapped
    compute = unwrapped.compute_reward  # type: ignore[attr-defined]
    is_success = getattr(unwrapped, "_is_success", None)

    def pairwise(fn: Any, dtype: type, achieved: np.ndarray, desired: np.ndarray) -> np.ndarray:
        """`fn` of the env on the goal pairs flattened to rows, shaped back to the leading
        axes the two broadcast to."""
        achieved, desired = np.asarray(achieved), np.asarray(desired)
        lead = np.broadcast_shapes(achieved.shape[:-1], desired.shape[:-1])
        rows = [np.broadcast_to(x, (*lead, spec.goal_dim)).reshape(-1, spec.goal_dim)
                for x in (achieved, desired)]
        return np.asarray(fn(*rows), dtype).reshape(lead)

    def reward(achieved: np.ndarray, desired: np.ndarray) -> np.ndarray:
        return pairwise(lambda a, d: compute(a, d, {}), np.float32, achieved, desired)

    def success(achieved: np.ndarray, desired: np.ndarray) -> np.ndarray:
        if is_success is not None:
            return pairwise(is_success, bool, achieved, desired)
        return reward(achieved, desired) >= reward(desired, desired)

    return EnvRule(reward=reward, success=success)


set_env_rule_maker(make_env_rule)
