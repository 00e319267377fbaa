"""Normaliser: the reference arithmetic (mean, eps-floored std, clip), incremental == one-shot,
state round trip and the validation of adopted state."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.rl.normalizer import STAT_KEYS, Normalizer


def _data(seed: int, shape: tuple[int, ...]) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(loc=3.0, scale=2.0, size=shape)


@pytest.mark.parametrize(
    "shape", [(500, 4), (7, 50, 4), (1, 4)], ids=["2d", "leading-3d", "single-row"]
)
def test_stats_equal_numpy_mean_and_population_std(shape: tuple[int, ...]) -> None:
    v = _data(0, shape)
    norm = Normalizer(4, eps=1e-6, clip_range=np.inf)
    norm.update(v)
    norm.recompute_stats()
    flat = v.reshape(-1, 4)
    np.testing.assert_allclose(norm.mean, flat.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(norm.std, np.maximum(flat.std(axis=0), 1e-6), rtol=1e-9)
    assert norm.count == flat.shape[0]
    np.testing.assert_allclose(norm.normalize(v),
                               ((v - flat.mean(0)) / np.maximum(flat.std(0), 1e-6)),
                               rtol=1e-5, atol=1e-5)


def test_std_floor_is_eps_for_constant_inputs() -> None:
    v = np.zeros((100, 3))
    v[:, 0] = 7.0  # constant: variance 0 → std = eps
    v[:, 1] = np.linspace(-1, 1, 100)  # large variance: untouched by the floor
    v[:, 2] = 7.0 + np.array([0.001, -0.001] * 50)  # std 0.001 < eps=0.01 → eps
    norm = Normalizer(3, eps=0.01)
    norm.update(v)
    norm.recompute_stats()
    assert norm.std[0] == pytest.approx(0.01)
    assert norm.std[1] == pytest.approx(v[:, 1].std())
    assert norm.std[2] == pytest.approx(0.01)


@pytest.mark.parametrize("clip", [5.0, 1.5], ids=["clip5", "clip1.5"])
def test_normalize_clips_to_clip_range(clip: float) -> None:
    norm = Normalizer(2, clip_range=clip)
    norm.update(_data(1, (1000, 2)))
    norm.recompute_stats()
    far = np.array([[1e6, -1e6], [3.0, 3.0]])
    out = norm.normalize(far)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out[0], [clip, -clip])
    assert np.all(np.abs(out[1]) < clip)


def test_before_any_data_normalize_is_identity_then_clip() -> None:
    norm = Normalizer(3)
    norm.recompute_stats()  # no data: stays mean 0, std 1
    np.testing.assert_array_equal(norm.normalize(np.array([0.5, -2.0, 9.0])),
                                  np.array([0.5, -2.0, 5.0], np.float32))


def test_update_without_recompute_leaves_normalize_unchanged() -> None:
    norm = Normalizer(2)
    norm.update(_data(2, (100, 2)))
    norm.recompute_stats()
    x = np.array([1.0, 2.0])
    before = norm.normalize(x)
    norm.update(_data(3, (100, 2)) + 50.0)
    np.testing.assert_array_equal(norm.normalize(x), before)


def test_incremental_updates_equal_one_shot() -> None:
    chunks = [_data(s, (n, 5)) for s, n in ((10, 37), (11, 1), (12, 200), (13, 64))]
    inc = Normalizer(5)
    for chunk in chunks:
        inc.update(chunk)
        inc.recompute_stats()
    once = Normalizer(5)
    once.update(np.concatenate(chunks))
    once.recompute_stats()
    for key in STAT_KEYS:
        np.testing.assert_allclose(inc.state_dict()[key], once.state_dict()[key], rtol=1e-12)


def test_state_round_trip_reproduces_normalize() -> None:
    src = Normalizer(4)
    src.update(_data(4, (300, 4)))
    src.recompute_stats()
    state = src.state_dict()
    assert set(state) == set(STAT_KEYS)
    # the state dict is a copy, not a view of the live statistics
    state["mean"][:] = 123.0
    assert not np.any(src.mean == 123.0)
    state = src.state_dict()
    dst = Normalizer(4)
    dst.load_state_dict(state)
    x = _data(5, (10, 4))
    np.testing.assert_array_equal(dst.normalize(x), src.normalize(x))
    # continuing to accumulate after adoption equals continuing in the source
    more = _data(6, (50, 4))
    for n in (src, dst):
        n.update(more)
        n.recompute_stats()
    np.testing.assert_array_equal(dst.mean, src.mean)
    np.testing.assert_array_equal(dst.std, src.std)


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("mean", np.zeros(3), "shape"),
        ("std", np.zeros(4), "std"),
        ("sum", np.full(4, np.nan), "NaN"),
        ("count", np.asarray(-1.0), "count"),
        ("count", np.asarray(2.5), "count"),
    ],
    ids=["wrong-shape", "zero-std", "nan", "negative-count", "fractional-count"],
)
def test_load_state_dict_rejects_bad_state_and_changes_nothing(
    key: str, value: np.ndarray, match: str
) -> None:
    src = Normalizer(4)
    src.update(_data(7, (20, 4)))
    src.recompute_stats()
    dst = Normalizer(4)
    before = dst.state_dict()
    bad = src.state_dict()
    bad[key] = value
    with pytest.raises(ValueError, match=match):
        dst.load_state_dict(bad)
    for k in STAT_KEYS:
        np.testing.assert_array_equal(dst.state_dict()[k], before[k])


def test_load_state_dict_requires_every_key() -> None:
    state = Normalizer(2).state_dict()
    del state["sumsq"]
    with pytest.raises(ValueError, match="sumsq"):
        Normalizer(2).load_state_dict(state)


def test_update_rejects_wrong_last_axis() -> None:
    with pytest.raises(ValueError, match="size=3"):
        Normalizer(3).update(np.zeros((4, 2)))
