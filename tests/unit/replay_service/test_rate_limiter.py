"""The rate limiter keeps updates per inserted episode at ρ within its stated bound and never
holds both sides at once."""

import numpy as np
import pytest

from hercs.errors import ConfigError
from hercs.replay_service.rate_limiter import SampleToInsertRatio


def insert(limiter: SampleToInsertRatio) -> None:
    """One insert the way the table makes it: admitted, then stored."""
    limiter.admit_insert()
    limiter.store_admitted()


def make(**overrides) -> SampleToInsertRatio:
    kwargs = {"samples_per_insert": 10.0, "min_size_to_sample": 4, "error_buffer": 80.0,
              "max_request": 40}
    kwargs.update(overrides)
    return SampleToInsertRatio(**kwargs)


def test_sampling_waits_for_min_size() -> None:
    limiter = make()
    for _ in range(3):
        assert limiter.can_insert() and not limiter.can_sample(1)
        insert(limiter)
    insert(limiter)
    assert limiter.can_sample(40)


@pytest.mark.parametrize("seed", [0, 1, 2], ids=lambda s: f"seed{s}")
@pytest.mark.parametrize("actor_speed", [0.05, 0.5, 0.95], ids=["slow-actors", "even",
                                                                 "fast-actors"])
def test_ratio_held_within_bound_under_random_interleaving(seed: int, actor_speed: float) -> None:
    rng = np.random.default_rng(seed)
    limiter = make()
    rho, E, n = 10.0, 80.0, 40
    for _ in range(20_000):
        wants_insert = rng.random() < actor_speed
        can_i, can_s = limiter.can_insert(), limiter.can_sample(n)
        assert can_i or can_s, f"deadlock at inserts={limiter.inserts} samples={limiter.samples}"
        if (wants_insert and can_i) or not can_s:
            insert(limiter)
        else:
            limiter.record_sample(n)
        if limiter.inserts >= 4:
            # |S − ρ·(I − N_min)| ≤ E + n + ρ once sampling may start (module docstring).
            assert abs(limiter.samples - rho * (limiter.inserts - 4)) <= E + n + rho
    assert limiter.inserts > 100 and limiter.samples > 1000
    assert limiter.samples / limiter.inserts == pytest.approx(rho, rel=0.1)


def test_free_run_admits_everything() -> None:
    limiter = make(free_run=True)
    for _ in range(100):
        insert(limiter)
    assert limiter.can_insert() and limiter.can_sample(40)
    assert limiter.describe(inserts_waiting=0, samples_waiting=0) == "free-run"


def test_too_narrow_window_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"rate_tolerance_updates: got 20\.0"):
        make(error_buffer=20.0)


def test_a_restarted_limiter_is_balanced_at_its_recovered_inserts() -> None:
    limiter = make()
    limiter.restart_balanced(12)
    assert (limiter.inserts, limiter.samples, limiter.surplus) == (12, 120, 0.0)
    assert limiter.can_sample(40) and limiter.can_insert()
    with pytest.raises(ValueError, match="got -1 inserts"):
        limiter.restart_balanced(-1)
