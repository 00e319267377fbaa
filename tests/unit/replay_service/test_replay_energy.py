"""EBP trajectory energy against hand-computed trajectories (m = 1, g = 9.81, Δt = 0.04)."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.config import EnergyConfig
from hercs.replay_service.energy import trajectory_energy, transition_energy

# Lifted 4 cm in one step (v_z = 1 m/s), held, nudged 2 cm sideways (v_x = 0.5 m/s), held:
#   E_1 = 9.81·0.04 + ½·1²   = 0.8924   → e_1 = E_1 (the first transition's energy is its total)
#   E_2 = 0.3924 + 0         → e_2 = max(0, E_2 − E_1) = 0
#   E_3 = 0.3924 + ½·0.5²    → e_3 = 0.125
#   E_4 = 0.3924             → e_4 = 0
LIFT_THEN_STILL = [(0, 0, 0), (0, 0, 0.04), (0, 0, 0.04), (0.02, 0, 0.04), (0.02, 0, 0.04)]
# Dropped from 10 cm: E_1 = 9.81·(−0.04) + ½·1² = 0.1076; E_2 = −0.7848 + 0.5, E_3 = −0.7848:
# the potential is relative to z_0 and may be negative; losses never count.
FALLING = [(0, 0, 0.10), (0, 0, 0.06), (0, 0, 0.02), (0, 0, 0.02)]


@pytest.mark.parametrize(
    ("trajectory", "clip", "expected_e", "w_potential"),
    [
        (LIFT_THEN_STILL, 999.0, [0.8924, 0.0, 0.125, 0.0], 1.0),
        (LIFT_THEN_STILL, 0.5, [0.5, 0.0, 0.125, 0.0], 1.0),
        (LIFT_THEN_STILL, 0.1, [0.1, 0.0, 0.1, 0.0], 1.0),
        (LIFT_THEN_STILL, 999.0, [0.5, 0.0, 0.125, 0.0], 0.0),
        (FALLING, 999.0, [0.1076, 0.0, 0.0], 1.0),
    ],
    ids=["lift-unclipped", "lift-clip-0.5", "lift-clip-0.1", "lift-kinetic-only", "falling"],
)
def test_hand_computed_trajectories(
    trajectory: list, clip: float, expected_e: list, w_potential: float
) -> None:
    config = EnergyConfig(clip_energy=clip, w_potential=w_potential)
    ag = np.array(trajectory, dtype=np.float64)
    np.testing.assert_allclose(transition_energy(ag, config), expected_e, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(trajectory_energy(ag, config), sum(expected_e), rtol=1e-9)


@pytest.mark.parametrize(
    "position", [(0.0, 0.0, 0.0), (1.3, 0.7, 0.42)], ids=["origin", "on-table"]
)
def test_static_trajectory_has_zero_energy(position: tuple) -> None:
    ag = np.tile(np.array(position, np.float32), (51, 1))
    assert float(trajectory_energy(ag, EnergyConfig())) == 0.0


def test_every_transition_energy_lies_in_zero_to_clip() -> None:
    """Random jumps of up to 10 cm per step: every e_t ∈ [0, clip], and the clip is reached."""
    rng = np.random.default_rng(0)
    ag = np.cumsum(rng.uniform(-0.1, 0.1, size=(64, 51, 3)), axis=1)
    config = EnergyConfig(clip_energy=0.5)
    e = transition_energy(ag, config)
    assert e.shape == (64, 50)
    assert e.min() >= 0.0 and e.max() <= 0.5
    assert np.mean(e == 0.5) > 0.1


def test_batched_equals_one_at_a_time() -> None:
    rng = np.random.default_rng(1)
    ag = np.cumsum(rng.normal(0, 0.01, size=(8, 51, 3)), axis=1).astype(np.float32)
    config = EnergyConfig()
    batched = trajectory_energy(ag, config)
    assert batched.shape == (8,)
    np.testing.assert_allclose(batched, [trajectory_energy(a, config) for a in ag], rtol=1e-12)
