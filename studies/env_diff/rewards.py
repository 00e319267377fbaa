"""4. Reward and success: `compute_reward` and `is_success` of both envs and
`hercs.rl.task_registry.fetch_reward` on the same goal pairs."""

from __future__ import annotations

from typing import Any

import numpy as np

from hercs.rl.task_registry import fetch_reward
from studies.env_diff.sim import Sim


def reward_check(s1: Sim, s4: Sim, n: int) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    ag = rng.uniform(-0.1, 0.1, size=(n, 3)) + np.array([1.3, 0.75, 0.42])
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    # half the distances near the 5 cm threshold
    dist = np.where(rng.uniform(size=n) < 0.5, rng.uniform(0.045, 0.055, n),
                    rng.uniform(0, 0.2, n))
    dg = ag + direction * dist[:, None]
    r1 = s1.u.compute_reward(ag, dg, {})
    r4 = s4.u.compute_reward(ag, dg, {})
    ours = fetch_reward(ag, dg, 0.05)
    ok1 = s1.u._is_success(ag, dg)
    ok4 = s4.u._is_success(ag, dg)
    return {"pairs": n,
            "compute_reward_equal": bool(np.array_equal(r1, r4)),
            "is_success_equal": bool(np.array_equal(ok1, ok4)),
            "hercs_fetch_reward_equal": bool(np.array_equal(r1, ours)),
            "success_iff_reward_zero": bool(np.array_equal(ok1.astype(bool), r1 == 0)),
            "distance_threshold": [s1.u.distance_threshold, s4.u.distance_threshold],
            "reward_type": [s1.u.reward_type, s4.u.reward_type]}
