"""learner.precision: bf16 autocast of the online networks with fp32 master weights, Adam and
losses follows the fp32 update's trajectory closely (fp32 runs with autocast disabled, the
update test_ddpg.py checks); a bad value is refused with the key named."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hercs.config import DDPGConfig, HercsConfig, apply_overrides
from hercs.errors import ConfigError
from hercs.learner.ddpg import DDPGLearner
from hercs.rl.networks import to_arrays
from hercs.rl.task_registry import task_spec
from hercs.wire.batch import TransitionBatch
from tests.support import random_transition_batch, update_losses

SPEC = task_spec("push")
SMALL = DDPGConfig(hidden_size=64, batch_size=64)


def _batch(seed: int, b: int = 64) -> TransitionBatch:
    return random_transition_batch(SPEC, b, seed)


def _flat(learner: DDPGLearner) -> np.ndarray:
    return np.concatenate([a.ravel() for a in to_arrays(learner.actor).values()])


def test_bf16_follows_the_fp32_trajectory_with_fp32_master_weights_and_losses() -> None:
    fp32 = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    bf16 = DDPGLearner(spec=SPEC, config=SMALL, seed=0, precision="bf16")
    start = _flat(fp32)
    np.testing.assert_array_equal(start, _flat(bf16))
    losses: dict[str, list[float]] = {"fp32": [], "bf16": []}
    for step in range(30):
        batch = _batch(step % 5)
        losses["fp32"].append(update_losses(fp32, batch)["critic_loss"])
        losses["bf16"].append(update_losses(bf16, batch)["critic_loss"])
        if step % 10 == 9:
            fp32.update_targets()
            bf16.update_targets()
    assert all(p.dtype == torch.float32 for p in bf16.actor.parameters())
    assert all(p.dtype == torch.float32 for p in bf16.critic.parameters())
    assert all(v.dtype == torch.float32 for state in bf16.critic_optim.state.values()
               for v in state.values() if isinstance(v, torch.Tensor) and v.numel() > 1)
    # bf16 keeps ~3 significant digits: the losses agree to a few per cent, and the weights
    # moved the same way, far more than they differ
    np.testing.assert_allclose(losses["bf16"], losses["fp32"], rtol=0.02)
    moved = np.linalg.norm(_flat(fp32) - start)
    apart = np.linalg.norm(_flat(bf16) - _flat(fp32))
    assert apart < 0.1 * moved, (apart, moved)  # measured 0.05 here


def test_an_unknown_precision_is_refused_with_the_key_named() -> None:
    with pytest.raises(ConfigError,
                       match=r"learner\.precision: got 'fp16', must be one of fp32, bf16, tf32"):
        apply_overrides(HercsConfig(), ["learner.precision=fp16"])
    with pytest.raises(ConfigError, match=r"learner\.precision: got .int8."):
        DDPGLearner(spec=SPEC, config=SMALL, seed=0, precision="int8")
