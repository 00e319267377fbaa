"""Rollouts on real Fetch environments: shapes, reproducibility, success as the env reports."""

import numpy as np
import pytest

from hercs.actors.rollout import RolloutWorker, VectorRollout
from hercs.rl.envs import make_env
from hercs.rl.task_registry import task_spec
from hercs.wire.episode import EpisodeIdentity, expected_shapes


@pytest.mark.parametrize("task", ["reach", "push"])
def test_episode_shapes_and_success_flag(task: str) -> None:
    spec = task_spec(task)
    worker = RolloutWorker(spec=spec, env=make_env(spec), seed=0)
    rng = np.random.default_rng(0)
    try:
        for _ in range(3):
            ep = worker.run_episode(lambda o, g: rng.uniform(-1, 1, spec.action_dim))
            for name, shape in expected_shapes(spec).items():
                assert getattr(ep, name).shape == shape
                assert getattr(ep, name).dtype == np.float32
            assert ep.success == bool(spec.is_success(ep.ag[-1], ep.g[-1]))
            np.testing.assert_array_equal(ep.g, np.repeat(ep.g[:1], spec.episode_steps, 0))
        assert worker.env_steps == 3 * spec.episode_steps
    finally:
        worker.close()


def test_reach_with_a_scripted_controller_succeeds() -> None:
    """Moving the gripper towards the goal (ag is the gripper in Reach) must reach it, so the
    recorded success and goals are consistent with the physics."""
    spec = task_spec("reach")
    worker = RolloutWorker(spec=spec, env=make_env(spec), seed=1)
    try:
        ep = worker.run_episode(lambda o, g: np.append(np.clip((g - o[:3]) * 10, -1, 1), 0.0))
        assert ep.success
        assert np.linalg.norm(ep.ag[-1] - ep.g[-1]) < spec.distance_threshold
    finally:
        worker.close()


def test_same_seed_same_episodes() -> None:
    spec = task_spec("push")
    eps = []
    for _ in range(2):
        worker = RolloutWorker(spec=spec, env=make_env(spec), seed=7)
        eps.append([worker.run_episode(lambda o, g: np.zeros(4)) for _ in range(2)])
        worker.close()
    for a, b in zip(eps[0], eps[1], strict=True):
        np.testing.assert_array_equal(a.obs, b.obs)
        np.testing.assert_array_equal(a.g, b.g)
    assert not np.array_equal(eps[0][0].g, eps[0][1].g), "consecutive resets draw new goals"


def test_vector_rollout_is_n_rollout_workers_with_one_policy_call_per_step() -> None:
    """Three envs stepped side by side give, env for env and episode for episode, what three
    single-env workers with the same seeds give under the same (deterministic) policy, with
    one batched policy call per step instead of three."""
    spec = task_spec("push")
    seeds = [3, 4, 5]

    def controller(o: np.ndarray, g: np.ndarray) -> np.ndarray:
        o, g = np.atleast_2d(o), np.atleast_2d(g)  # push the gripper towards the goal
        return np.hstack([np.clip((g - o[:, :3]) * 5, -1, 1), np.full((len(o), 1), -1.0)])

    calls: list[int] = []

    def batched(o: np.ndarray, g: np.ndarray) -> np.ndarray:
        calls.append(len(o))
        return controller(o, g)

    vector = VectorRollout(spec=spec, envs=[make_env(spec) for _ in seeds], seeds=seeds)
    singles = [RolloutWorker(spec=spec, env=make_env(spec), seed=s) for s in seeds]
    try:
        for _ in range(2):
            together = vector.run_episodes(batched)
            apart = [w.run_episode(lambda o, g: controller(o, g)[0]) for w in singles]
            for a, b in zip(together, apart, strict=True):
                for name in ("obs", "ag", "g", "actions"):
                    np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)
                assert a.success == b.success
        assert calls == [3] * (2 * spec.episode_steps)
        assert vector.env_steps == 2 * 3 * spec.episode_steps
    finally:
        vector.close()
        for w in singles:
            w.close()


def test_episodes_are_made_with_their_identity() -> None:
    """An actor's episodes get their actor id, seq (one per env, in env order) and policy
    version where they are made: nothing tags them after."""
    spec = task_spec("reach")
    vector = VectorRollout(spec=spec, envs=[make_env(spec) for _ in range(3)], seeds=[1, 2, 3])
    try:
        made = vector.run_episodes(lambda o, g: np.zeros((len(o), 4)), EpisodeIdentity(
            actor_id="a@k1", first_seq=12, policy_version=5))
        assert [(e.actor_id, e.seq, e.policy_version) for e in made] == [
            ("a@k1", 12, 5), ("a@k1", 13, 5), ("a@k1", 14, 5)]
        plain = vector.run_episodes(lambda o, g: np.zeros((len(o), 4)))
        assert {(e.actor_id, e.policy_version) for e in plain} == {("", -1)}
    finally:
        vector.close()
