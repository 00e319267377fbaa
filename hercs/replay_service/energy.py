"""Trajectory energy of energy-based prioritisation (EBP, Zhao & Tresp 2018).

Each transition's gain in potential plus kinetic energy of the achieved goal, clipped to
[0, clip_energy], summed over t = 1..T (docs/DESIGN.md §4.5); computed once per episode on
insert, in float64. `points` and `hand` (`TaskSpec.energy`) extend it beyond Fetch: `points`
sums the terms over an achieved goal's 3-d points (ours: EBP has no energy for such tasks);
`hand` adds the EBP reference's rotational term over Euler-angle rates. As there, the angles
are not unwrapped: a crossing of ±π counts as a fast turn, and the clip bounds what it adds.
"""

from __future__ import annotations

import numpy as np

from hercs.config import EnergyConfig
from hercs.errors import ConfigError


def transition_energy(ag: np.ndarray, config: EnergyConfig, kind: str = "points") -> np.ndarray:
    """Clipped per-transition energies e_1..e_T: shape (..., T) from ag of shape
    (..., T+1, goal_dim): goal_dim = 3k for `points`, 7 for `hand`.

    Exactly the reference's `ReplayBufferEnergy.store_episode` (repository
    ruizhaogit/EnergyBasedPrioritization, baselines/her/replay_buffer.py, Fetch branch):
    heights ``ag[:, 1:, 2] − ag[:, 0, 2]``, velocities ``np.diff(ag, axis=1) / Δt`` summed over
    the three axes, ``energy_transition = energy_total`` with ``[:, 1:]`` replaced by
    ``np.diff(energy_total)``, then ``np.clip(…, 0, clip_energy)``. Their defaults are m = 1,
    g = 9.81, Δt = 0.04, both weights 1; clip_energy 0.5 is their PickAndPlace setting, and
    2.5 their hand tasks' (`--set energy.clip_energy=2.5`)."""
    ag = np.asarray(ag, dtype=np.float64)
    if kind not in ("points", "hand"):
        raise ConfigError(f"energy: a task with energy {kind!r} has no trajectory energy")
    width = 7 if kind == "hand" else None
    if (ag.ndim < 2 or ag.shape[-2] < 2 or ag.shape[-1] == 0
            or (ag.shape[-1] % 3 if width is None else ag.shape[-1] != width)):
        want = "7" if width else "3k"
        raise ConfigError(f"energy: ag must have shape (..., T+1, {want}) with T >= 1 for "
                          f"{kind} energy, got {ag.shape}")
    points = ag[..., :3] if kind == "hand" else ag
    points = points.reshape(*points.shape[:-1], -1, 3)  # (..., T+1, k, 3)
    height = (points[..., 1:, :, 2] - points[..., :1, :, 2]).sum(axis=-1)
    potential = config.mass * config.gravity * height
    velocity = np.diff(points, axis=-3) / config.delta_t
    kinetic = 0.5 * config.mass * np.sum(velocity**2, axis=(-2, -1))
    total = config.w_potential * potential + config.w_kinetic * kinetic
    if kind == "hand":
        angular = np.diff(euler_angles(ag[..., 3:7]), axis=-2) / config.delta_t
        total = total + config.w_rotational * 0.5 * config.inertia * np.sum(angular**2, axis=-1)
    per_transition = total.copy()
    per_transition[..., 1:] = np.diff(total, axis=-1)
    return np.clip(per_transition, 0.0, config.clip_energy)


def trajectory_energy(ag: np.ndarray, config: EnergyConfig, kind: str = "points") -> np.ndarray:
    """Σ_t e_t: a 0-d array for one trajectory (T+1, d), shape (N,) for a batch (N, T+1, d)."""
    return transition_energy(ag, config, kind).sum(axis=-1)


def euler_angles(quaternion: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of unit quaternions (w, x, y, z) in the last axis: rotations about
    x, y and z applied in that order (the reference's conversion; pitch clamped to ±π/2)."""
    w, x, y, z = np.moveaxis(np.asarray(quaternion, np.float64), -1, 0)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)
