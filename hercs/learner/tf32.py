"""TF32 arithmetic of matrix products, emulated on any device (`learner.precision=tf32`).

Inside `TF32Products` every matrix product torch dispatches (forward and backward: the mode
sits below autograd) rounds its float32 operands to TF32's 10 mantissa bits (`round_to_tf32`,
a rule chosen to match cuBLAS's own TF32 products, docs/results/learner_cuda.md) and multiplies
in fp32, as the authors' torch 1.10.1 did by default on an Ampere-or-newer GPU (which GPU they
trained on is not published: on an older one their products were fp32). Element-wise ops,
Adam and the losses stay fp32.
"""

from __future__ import annotations

from typing import Any

import torch
from torch.utils._python_dispatch import TorchDispatchMode

TF32_DROPPED_BITS = 13
"""fp32's 23 mantissa bits less TF32's 10."""
_HALF_UNIT = 1 << (TF32_DROPPED_BITS - 1)
_KEEP_MASK = ~((1 << TF32_DROPPED_BITS) - 1)
_EXPONENT_ALL_ONES = 0x7F800000

_PRODUCTS = {
    torch.ops.aten.mm.default: (0, 1),
    torch.ops.aten.addmm.default: (1, 2),  # addmm(bias, a, b): the bias is added in fp32
    torch.ops.aten.bmm.default: (0, 1),
    torch.ops.aten.baddbmm.default: (1, 2),
}
"""The matrix products an MLP's forward and backward passes dispatch, and which of their
arguments are the multiplied operands."""


def round_to_tf32(tensor: torch.Tensor) -> torch.Tensor:
    """A float32 tensor with each value rounded to TF32 (10 mantissa bits), still float32;
    other dtypes are returned as they are.

    To nearest, ties to even, on the magnitude's bit pattern: add just under half a unit of
    the 13 dropped bits plus the kept last bit, then clear them (the rule of cuBLAS's own
    TF32 products, docs/results/learner_cuda.md). Infinities and NaNs pass unchanged; a
    finite value within half a TF32 unit of the largest float rounds to infinity, as the
    hardware's would."""
    if tensor.dtype != torch.float32:
        return tensor
    bits = tensor.contiguous().view(torch.int32)
    special = (bits & _EXPONENT_ALL_ONES) == _EXPONENT_ALL_ONES  # inf and NaN keep their bits
    # the sign bit is untouched (sign and magnitude): a tie goes to the even neighbour
    kept_last_bit = (bits >> TF32_DROPPED_BITS) & 1
    rounded = (bits + (_HALF_UNIT - 1) + kept_last_bit) & _KEEP_MASK
    return torch.where(special, bits, rounded).view(torch.float32).view_as(tensor)


class TF32Products(TorchDispatchMode):
    """Within this mode, matrix products round their float32 operands to TF32 first."""

    def __torch_dispatch__(self, func: Any, types: Any, args: tuple[Any, ...] = (),
                           kwargs: dict[str, Any] | None = None) -> Any:
        operands = _PRODUCTS.get(func)
        if operands is not None:
            args = tuple(round_to_tf32(a) if i in operands and isinstance(a, torch.Tensor)
                         else a for i, a in enumerate(args))
        return func(*args, **(kwargs or {}))
