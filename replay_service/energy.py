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
"""

from __future__ import annotations

import numpy as np

from hercs.config import EnergyConfig
from hercs.errors import ConfigError


def transition_energy(ag: np.ndarray, config: EnergyConfig) -> np.ndarray:
    """Clipped per-transition energies e_1..e_T: shape (..., T) from ag of shape (..., T+1, 3)."""
    ag = np.asarray(ag, dtype=np.float64)
    if ag.ndim < 2 or ag.shape[-2] < 2 or ag.shape[-1] != 3:
        raise ConfigError(f"energy: ag must have shape (..., T+1, 3) with T >= 1, got {ag.shape}")
    height = ag[..., 1:, 2] - ag[..., :1, 2]
    potential = config.mass * config.gravity * height
    velocity = np.diff(ag, axis=-2) / config.delta_t
    kinetic = 0.5 * config.mass * np.sum(velocity**2, axis=-1)
    total = config.w_potential * potential + config.w_kinetic * kinetic
    per_transition = total.copy()
    per_transition[..., 1:] = np.diff(total, axis=-1)
    return np.clip(per_transition, 0.0, config.clip_energy)


def trajectory_energy(ag: np.ndarray, config: EnergyConfig) -> np.ndarray:
    """Σ_t e_t: a 0-d array for one trajectory (T+1, 3), shape (N,) for a batch (N, T+1, 3)."""
    return transition_energy(ag, config).sum(axis=-1)
