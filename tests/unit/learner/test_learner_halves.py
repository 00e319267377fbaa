"""The update's two halves on two threads (`parallel_halves`): the same numbers, bit for bit, as
one thread, and as the update written the reference's way (the actor's loss through the critic
with the critic's parameters switched off and on), in every precision."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from hercs.config import DDPGConfig
from hercs.learner.ddpg import DDPGLearner, critic_target, return_bounds
from hercs.rl.networks import preprocess
from hercs.rl.task_registry import task_spec
from tests.support import random_transition_batch, update_losses

SPEC = task_spec("push")
CONFIG = DDPGConfig(batch_size=64)  # the reference widths: 3 × 256
UPDATES = 12


def reference_update(learner: DDPGLearner, batch) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """One fp32 update in the reference's order: target, critic loss, actor loss through the
    critic with its parameters' requires_grad off, actor step, critic step."""
    cfg, spec = learner.config, learner.spec
    s = torch.from_numpy(preprocess(batch.o, batch.g, learner.o_norm, learner.g_norm,
                                    cfg.clip_obs))
    s2 = torch.from_numpy(preprocess(batch.o2, batch.g, learner.o_norm, learner.g_norm,
                                     cfg.clip_obs))
    u, r = torch.from_numpy(np.array(batch.u)), torch.from_numpy(batch.r.reshape(-1, 1))
    y = critic_target(r, s2, actor_target=learner.actor_target,
                      critic_target=learner.critic_target, gamma=cfg.gamma,
                      clip_return=return_bounds(spec, cfg.gamma))
    q = learner.critic(s, u)
    critic_loss = (y - q).pow(2).mean()
    pi = learner.actor(s)
    action_l2 = (pi / spec.max_action).pow(2).mean()
    learner.critic.requires_grad_(False)
    actor_loss = -learner.critic(s, pi).mean() + cfg.action_l2 * action_l2
    learner.critic.requires_grad_(True)
    learner.actor_optim.zero_grad(set_to_none=True)
    actor_loss.backward()
    learner.actor_optim.step()
    learner.critic_optim.zero_grad(set_to_none=True)
    critic_loss.backward()
    learner.critic_optim.step()
    return {"critic_loss": critic_loss.item(), "actor_loss": actor_loss.item()}


def _state(learner: DDPGLearner) -> list[torch.Tensor]:
    tensors = [p.detach() for net in (learner.actor, learner.critic) for p in net.parameters()]
    for optim in (learner.actor_optim, learner.critic_optim):
        tensors += [v for state in optim.state.values() for v in state.values()
                    if isinstance(v, torch.Tensor)]
    return tensors


def _run(learner: DDPGLearner, update=None) -> list[dict[str, float]]:  # type: ignore[no-untyped-def]
    rows = []
    for i in range(UPDATES):
        batch = random_transition_batch(SPEC, CONFIG.batch_size, seed=i)
        rows.append((update or update_losses)(learner, batch))
        if i % 4 == 3:
            learner.update_targets()
    return rows


@pytest.mark.parametrize("precision", ["fp32", "bf16", "tf32"])
def test_two_threads_give_the_numbers_of_one(precision: str) -> None:
    one = DDPGLearner(spec=SPEC, config=CONFIG, seed=3, precision=precision)
    two = DDPGLearner(spec=SPEC, config=CONFIG, seed=3, precision=precision,
                      parallel_halves=True)
    assert _run(one) == _run(two)
    for a, b in zip(_state(one), _state(two), strict=True):
        assert torch.equal(a, b)
    assert len(_state(one)) == 2 * 8 + 2 * 8 * 3  # 16 parameters, Adam's step, m and v each


def test_both_give_the_numbers_of_the_reference_update() -> None:
    reference = DDPGLearner(spec=SPEC, config=CONFIG, seed=5)
    two = DDPGLearner(spec=SPEC, config=CONFIG, seed=5, parallel_halves=True)
    want = _run(reference, reference_update)
    got = _run(two)
    assert [{k: row[k] for k in ("critic_loss", "actor_loss")} for row in got] == want
    for a, b in zip(_state(reference), _state(two), strict=True):
        assert torch.equal(a, b)


def test_the_critic_half_runs_on_its_own_single_threaded_thread() -> None:
    learner = DDPGLearner(spec=SPEC, config=CONFIG, seed=0, parallel_halves=True)
    seen: list[tuple[str, int]] = []
    half = learner._critic_half

    def spy(*args):  # type: ignore[no-untyped-def]
        seen.append((threading.current_thread().name, torch.get_num_threads()))
        return half(*args)

    learner._critic_half = spy  # type: ignore[method-assign]
    before = torch.get_num_threads()
    torch.set_num_threads(1)  # what every service sets (hercs/net/threads.py)
    try:
        update_losses(learner, random_transition_batch(SPEC, CONFIG.batch_size, seed=0))
    finally:
        torch.set_num_threads(before)
    assert len(seen) == 1 and seen[0][0].startswith("critic-half")
    assert seen[0][1] == 1  # torch's one-thread setting reaches the second thread


def test_an_error_in_the_critic_half_reaches_the_caller() -> None:
    learner = DDPGLearner(spec=SPEC, config=CONFIG, seed=0, parallel_halves=True)
    batch = random_transition_batch(SPEC, CONFIG.batch_size, seed=0)
    update_losses(learner, batch)
    learner.critic_target.net[0].weight.data = torch.zeros(3, 3)  # a broken target network
    with pytest.raises(RuntimeError):
        update_losses(learner, batch)


def test_train_sums_on_the_device_what_each_update_reads() -> None:
    """The loop's `train` + one `loss_means` over an epoch's updates (no host read per update)
    against the mean of each update's own losses (read after every update), summed in
    float64: the same numbers."""
    summed = DDPGLearner(spec=SPEC, config=CONFIG, seed=4, parallel_halves=True)
    returned = DDPGLearner(spec=SPEC, config=CONFIG, seed=4)
    rows = []
    for i in range(UPDATES):
        batch = random_transition_batch(SPEC, CONFIG.batch_size, seed=i)
        summed.train(batch)
        rows.append(update_losses(returned, batch))
    # the sums hold numbers, not the updates' autograd graphs (a chain of them leaked memory)
    assert not summed.loss_sums.requires_grad and summed.loss_sums.grad_fn is None
    means = summed.loss_means()
    assert means == {key: sum(row[key] for row in rows) / UPDATES for key in rows[0]}
    assert summed.updates == returned.updates == UPDATES
    for a, b in zip(_state(summed), _state(returned), strict=True):
        assert torch.equal(a, b)
    assert all(np.isnan(v) for v in summed.loss_means().values())  # reset by the read


def test_an_error_in_the_actor_half_waits_for_the_critic_half() -> None:
    """The next update must never meet a critic half still writing gradients."""
    learner = DDPGLearner(spec=SPEC, config=CONFIG, seed=0, parallel_halves=True)
    actor_failed, finished = threading.Event(), threading.Event()
    half = learner._critic_half

    def slow_critic_half(*args):  # type: ignore[no-untyped-def]
        assert actor_failed.wait(timeout=60)  # starts its work only once the actor half failed
        result = half(*args)
        finished.set()
        return result

    def failing_actor_half(s):  # type: ignore[no-untyped-def]
        actor_failed.set()
        raise RuntimeError("actor half failed")

    learner._critic_half = slow_critic_half  # type: ignore[method-assign]
    learner._actor_half = failing_actor_half  # type: ignore[method-assign]
    with pytest.raises(RuntimeError, match="actor half failed"):
        update_losses(learner, random_transition_batch(SPEC, CONFIG.batch_size, seed=0))
    assert finished.is_set()
