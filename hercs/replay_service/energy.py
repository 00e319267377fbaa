"""Trajectory energy of energy-based prioritisation (EBP, Zhao & Tresp 2018).

From the achieved-goal (object) trajectory ag_0..ag_T, with m, g, Δt and the weights from
`EnergyConfig`, for steps t = 1..T:

    U_t = m·g·(z_t − z_0)                         potential, relative to the start height
    K_t = ½·m·‖(ag_t − ag_{t−1}) / Δt‖²           kinetic, from the step's finite difference
    E_t = w_potential·U_t + w_kinetic·K_t         total energy after transition t

    e_1 = clip(E_1, 0, clip_energy)               the first transition's energy is its total
    e_t = clip(E_t − E_{t−1}, 0, clip_energy)     t = 2..T: only energy gains count
    trajectory energy = Σ_{t=1..T} e_t

This is exactly the reference's `ReplayBufferEnergy.store_episode` (repository
ruizhaogit/EnergyBasedPrioritization, baselines/her/replay_buffer.py, Fetch branch): heights
``ag[:, 1:, 2] − ag[:, 0, 2]``, velocities ``np.diff(ag, axis=1) / Δt`` summed over the three
axes, ``energy_transition = energy_total`` with ``[:, 1:]`` replaced by ``np.diff(energy_total)``,
then ``np.clip(…, 0, clip_energy)`` and a sum over time. Their defaults are m = 1, g = 9.81,
Δt = 0.04, both weights 1; clip_energy 0.5 is their PickAndPlace setting. Computed in float64
(the reference's buffers are float64).

Beyond Fetch (`TaskSpec.energy`, hercs.rl.task_registry.ENERGIES):
- `points`: an achieved goal of k 3-d points (Fetch: k = 1, the object; HandReach: k = 5, the
  fingertips) gives each point the terms above and sums them: U_t = m·g·Σ_i (z_it − z_i0),
  K_t = ½·m·Σ_i ‖Δag_i/Δt‖². Our extension for HandReach (the EBP paper has no energy for it).
- `hand`: a position then a (w, x, y, z) quaternion (the hand manipulation tasks): the
  position's U_t and K_t, plus the reference's rotational term R_t = ½·I·‖Δθ/Δt‖² over the
  Euler angles θ = (roll, pitch, yaw) of the quaternion, weighted by `w_rotational` (the
  reference's hand branch, clip 2.5 for its hand tasks: `--set energy.clip_energy=2.5`). As
  in the reference, the angles are not unwrapped: a crossing of ±π counts as a fast turn, and
  the clip bounds what it can add.
"""

from __future__ import annotations

import numpy as np

from hercs.config import EnergyConfig
from hercs.errors import ConfigError


def transition_energy(ag: np.ndarray, config: EnergyConfig, kind: str = "points") -> np.ndarray:
    """Clipped per-transition energies e_1..e_T: shape (..., T) from ag of shape
    (..., T+1, goal_dim): goal_dim = 3k for `points`, 7 for `hand`."""
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
