"""learner.precision=tf32: matrix products with operands rounded to TF32's 10 mantissa bits,
forward and backward, the rest fp32 (hercs/learner/tf32.py)."""

from __future__ import annotations

import numpy as np
import torch

from hercs.config import DDPGConfig
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.tf32 import TF32Products, round_to_tf32
from hercs.rl.networks import to_arrays
from hercs.rl.task_registry import task_spec
from hercs.wire.batch import TransitionBatch
from tests.support import random_transition_batch, update_losses

SPEC = task_spec("push")
SMALL = DDPGConfig(hidden_size=64, batch_size=64)


def _mantissa_low_bits(x: torch.Tensor) -> torch.Tensor:
    return x.view(torch.int32) & ((1 << 13) - 1)


def test_rounding_keeps_ten_mantissa_bits_to_nearest_with_ties_to_even() -> None:
    x = torch.from_numpy(np.random.default_rng(0).normal(size=10_000).astype(np.float32))
    r = round_to_tf32(x)
    assert r.dtype == torch.float32 and r.shape == x.shape
    assert int(_mantissa_low_bits(r).abs().max()) == 0  # 13 low bits cleared
    # to nearest: within half a unit of the 10th bit, i.e. 2^-11 of the value
    assert float(((r - x).abs() / x.abs()).max()) <= 2.0 ** -11
    one = 1.0
    unit = 2.0 ** -10  # TF32's spacing just above 1
    # ties: 1 + u/2 lies between 1 (even) and 1 + u (odd); 1 + 3u/2 between 1 + u and 1 + 2u
    values = torch.tensor([one + unit / 2, -(one + unit / 2), one + 3 * unit / 2,
                           one + unit / 4, 3 * unit / 4 + one], dtype=torch.float32)
    np.testing.assert_array_equal(round_to_tf32(values).numpy(),
                                  np.array([one, -one, one + 2 * unit, one, one + unit],
                                           dtype=np.float32))
    exact = torch.tensor([0.0, -0.0, 1.0, 0.5, -1024.0, 1.0 + unit], dtype=torch.float32)
    np.testing.assert_array_equal(round_to_tf32(exact).numpy(), exact.numpy())
    special = round_to_tf32(torch.tensor([float("inf"), float("-inf"), float("nan")]))
    assert special[0] == float("inf") and special[1] == float("-inf") and special[2].isnan()
    ints = torch.arange(5)
    assert round_to_tf32(ints) is ints  # not float32: untouched


def test_products_inside_the_mode_multiply_rounded_operands_in_fp32() -> None:
    gen = torch.Generator().manual_seed(1)
    a, b, bias = (torch.randn(*shape, generator=gen) for shape in ((32, 48), (48, 16), (16,)))
    with TF32Products():
        mm, addmm = a @ b, torch.nn.functional.linear(a, b.T, bias)
    expected = round_to_tf32(a) @ round_to_tf32(b)
    torch.testing.assert_close(mm, expected, rtol=0, atol=0)
    torch.testing.assert_close(addmm, expected + bias, rtol=1e-6, atol=1e-6)
    assert not torch.equal(mm, a @ b)  # the rounding is there


def test_the_backward_products_are_rounded_too() -> None:
    gen = torch.Generator().manual_seed(2)
    x = torch.randn(8, 24, generator=gen)
    w = torch.randn(24, 12, generator=gen, requires_grad=True)
    upstream = torch.randn(8, 12, generator=gen)
    with TF32Products():
        (x @ w).backward(upstream)
    # dL/dw = xᵀ · upstream, itself a product of rounded operands
    torch.testing.assert_close(w.grad, round_to_tf32(x).T @ round_to_tf32(upstream),
                               rtol=0, atol=0)


def _flat(learner: DDPGLearner) -> np.ndarray:
    return np.concatenate([a.ravel() for a in to_arrays(learner.actor).values()])


def _batch(seed: int) -> TransitionBatch:
    return random_transition_batch(SPEC, 64, seed)


def test_a_tf32_learner_follows_fp32_closely_but_not_exactly() -> None:
    fp32 = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    tf32 = DDPGLearner(spec=SPEC, config=SMALL, seed=0, precision="tf32")
    start = _flat(fp32)
    for step in range(30):
        a, b = update_losses(fp32, _batch(step % 5)), update_losses(tf32, _batch(step % 5))
        assert abs(a["critic_loss"] - b["critic_loss"]) <= 1e-2 * max(1.0, a["critic_loss"])
        if step % 10 == 9:
            fp32.update_targets()
            tf32.update_targets()
    moved = np.linalg.norm(_flat(fp32) - start)
    apart = np.linalg.norm(_flat(tf32) - _flat(fp32))
    # TF32 keeps ~3 decimal digits per operand, with fp32 sums: apart, but far less than moved
    assert 0 < apart < 0.05 * moved, (apart, moved)
    assert all(p.dtype == torch.float32 for p in tf32.actor.parameters())
