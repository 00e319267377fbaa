"""learner.device: resolution, the refusal of a CUDA device that is not there, checkpoints
that always hold host tensors, and (where a GPU exists) the same update on CPU and CUDA."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hercs.config import DDPGConfig, HercsConfig, apply_overrides
from hercs.errors import ConfigError
from hercs.learner.ddpg import DDPGLearner, resolve_device
from hercs.rl.task_registry import task_spec
from hercs.wire.batch import TransitionBatch
from tests.support import random_transition_batch, update_losses

SPEC = task_spec("push")
SMALL = DDPGConfig(hidden_size=64, batch_size=32)
HAS_CUDA = torch.cuda.is_available()
NO_CUDA = "no CUDA device here (torch.cuda.is_available() is False): the GPU path is not run"


def _batch(seed: int, b: int = 32) -> TransitionBatch:
    return random_transition_batch(SPEC, b, seed)


def test_auto_is_cuda_only_where_torch_sees_a_gpu() -> None:
    assert resolve_device("auto").type == ("cuda" if HAS_CUDA else "cpu")
    assert resolve_device("cpu") == torch.device("cpu")


@pytest.mark.skipif(HAS_CUDA, reason="a CUDA device is present: asking for one is not an error")
def test_asking_for_cuda_without_one_says_what_to_do() -> None:
    with pytest.raises(ConfigError, match=r"learner\.device=cuda: torch sees no CUDA device"):
        resolve_device("cuda")
    with pytest.raises(ConfigError, match=r"use learner\.device=auto or cpu"):
        DDPGLearner(spec=SPEC, config=SMALL, seed=0, device="cuda:0")


@pytest.mark.parametrize("bad", ["tpu", "cpu:0", "cuda:x", "CUDA", ""])
def test_config_refuses_unknown_devices(bad: str) -> None:
    with pytest.raises(ConfigError, match=r"learner\.device"):
        apply_overrides(HercsConfig(), [f"learner.device={bad}"])
    assert apply_overrides(HercsConfig(), ["learner.device=cuda:1"]).learner.device == "cuda:1"


def test_device_path_on_the_cpu_matches_the_default_and_checkpoints_are_host_tensors() -> None:
    """The device code path (explicit torch.device, pinned-copy helper) on the CPU device
    gives bit-identical updates to the default learner, and its checkpoint holds only CPU
    tensors that load into a fresh learner."""
    default = DDPGLearner(spec=SPEC, config=SMALL, seed=3)
    explicit = DDPGLearner(spec=SPEC, config=SMALL, seed=3, device=torch.device("cpu"))
    for i in range(5):
        assert update_losses(default, _batch(i)) == update_losses(explicit, _batch(i))
    state = explicit.state_dict()
    tensors = [t for part in ("actor", "critic", "actor_target") for t in state[part].values()]
    tensors += [v for s in state["actor_optim"]["state"].values() for v in s.values()
                if isinstance(v, torch.Tensor)]
    assert tensors and all(t.device.type == "cpu" for t in tensors)
    restored = DDPGLearner(spec=SPEC, config=SMALL, seed=99)
    restored.load_state_dict(state)
    assert update_losses(restored, _batch(7)) == update_losses(explicit, _batch(7))


@pytest.mark.skipif(not HAS_CUDA, reason=NO_CUDA)
def test_the_same_updates_on_cuda_as_on_the_cpu() -> None:
    cpu = DDPGLearner(spec=SPEC, config=SMALL, seed=5, device="cpu")
    gpu = DDPGLearner(spec=SPEC, config=SMALL, seed=5, device="cuda")
    for i in range(20):
        a, b = update_losses(cpu, _batch(i)), update_losses(gpu, _batch(i))
        assert a.keys() == b.keys()
        for key in a:
            assert abs(a[key] - b[key]) <= 1e-3 * max(1.0, abs(a[key])), key
    for name, array in cpu.actor_weights().items():
        np.testing.assert_allclose(gpu.actor_weights()[name], array, atol=1e-3)
    moved = DDPGLearner(spec=SPEC, config=SMALL, seed=0, device="cpu")
    moved.load_state_dict(gpu.state_dict())  # a GPU run's checkpoint resumes on a CPU
    assert update_losses(moved, _batch(30)).keys() == a.keys()


def test_fused_adam_and_frozen_critic_match_the_plain_update() -> None:
    """The speed-ups of the update (fused Adam; no critic weight gradients from the actor's
    loss) change nothing but float rounding: after 10 updates the nets equal those of the
    plain update (loop Adam, critic gradients computed and discarded)."""
    fast = DDPGLearner(spec=SPEC, config=SMALL, seed=11)
    plain = DDPGLearner(spec=SPEC, config=SMALL, seed=11)
    plain.actor_optim = torch.optim.Adam(plain.actor.parameters(), lr=SMALL.lr_actor)
    plain.critic_optim = torch.optim.Adam(plain.critic.parameters(), lr=SMALL.lr_critic)
    plain._critic_params = []  # no freezing: the critic's grads from L_mu are computed
    for i in range(10):
        a, b = update_losses(fast, _batch(i)), update_losses(plain, _batch(i))
        for key in a:
            assert abs(a[key] - b[key]) <= 1e-4 * max(1.0, abs(b[key])), key
    for net in ("actor", "critic"):
        for (name, x), (_, y) in zip(getattr(fast, net).named_parameters(),
                                     getattr(plain, net).named_parameters(), strict=True):
            torch.testing.assert_close(x, y, rtol=1e-4, atol=1e-5, msg=f"{net}.{name}")
