"""DDPG learner: the clipped target, exact Polyak arithmetic, bounded actor, a learning sanity
check, checkpoint round trip, seeding that leaves the global torch RNG alone, and the weights
broadcast an actor can adopt."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from hercs.config import DDPGConfig
from hercs.learner.ddpg import DDPGLearner, critic_target, return_bounds
from hercs.rl.networks import Actor, Critic, preprocess
from hercs.rl.normalizer import Normalizer
from hercs.rl.policy import Policy
from hercs.rl.task_registry import task_spec
from tests.support import random_transition_batch as _batch
from tests.support import update_losses

SPEC = task_spec("push")
SMALL = DDPGConfig(hidden_size=64, batch_size=32)  # fast nets where the width does not matter


def _params(module: torch.nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


@pytest.mark.parametrize(
    ("bias", "clip", "expected"),
    [
        (100.0, True, "zero"),
        (-1000.0, True, "floor"),
        (-10.0, True, "unclipped"),
        (100.0, False, "unclipped"),
        (-1000.0, False, "unclipped"),
    ],
    ids=["above-0-clipped", "below-floor-clipped", "inside-untouched", "above-0-no-clip",
         "below-floor-no-clip"],
)
def test_critic_target_is_clipped_to_minus_one_over_one_minus_gamma_and_zero(
    bias: float, clip: bool, expected: str
) -> None:
    config = dataclasses.replace(SMALL, clip_return=clip)
    learner = DDPGLearner(spec=SPEC, config=config, seed=0)
    with torch.no_grad():
        last = learner.critic_target.net[-1]
        last.weight.zero_()
        last.bias.fill_(bias)  # Q'(s', ·) = bias everywhere
    b = 16
    r = -torch.ones(b, 1)
    r[::2] = 0.0
    s2 = torch.randn(b, SPEC.obs_dim + SPEC.goal_dim, generator=torch.Generator().manual_seed(0))
    y = critic_target(r, s2, actor_target=learner.actor_target,
                      critic_target=learner.critic_target, gamma=config.gamma,
                      clip_return=return_bounds(SPEC, config.gamma) if clip else None)
    unclipped = r + config.gamma * bias
    want = {"zero": torch.zeros_like(r),
            "floor": torch.full_like(r, -1.0 / (1.0 - config.gamma)),
            "unclipped": unclipped}[expected]
    torch.testing.assert_close(y, want)
    assert not y.requires_grad

    # the update regresses Q onto the same (clipped) target
    metrics = update_losses(learner, _batch(SPEC, b, seed=1))
    batch_r = _batch(SPEC, b, seed=1).r
    want_mean = {"zero": 0.0, "floor": -1.0 / (1.0 - config.gamma),
                 "unclipped": float(np.mean(batch_r + config.gamma * bias))}[expected]
    assert metrics["y_mean"] == pytest.approx(want_mean, rel=1e-5)


def test_reward_of_shape_b_is_not_broadcast_to_b_by_b() -> None:
    learner = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    twin = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    batch = _batch(SPEC, 8, seed=2)
    column = batch._replace(r=batch.r.reshape(8, 1))
    assert update_losses(learner, batch) == update_losses(twin, column)


@pytest.mark.parametrize("polyak", [0.95, 0.5, 0.0, 1.0], ids=["0.95", "0.5", "copy", "frozen"])
def test_polyak_update_arithmetic(polyak: float) -> None:
    config = dataclasses.replace(SMALL, polyak=polyak)
    learner = DDPGLearner(spec=SPEC, config=config, seed=0)
    for i in range(3):
        update_losses(learner, _batch(SPEC, 32, seed=10 + i))
    pairs = [(learner.actor, learner.actor_target), (learner.critic, learner.critic_target)]
    before = [(_params(net), _params(targ)) for net, targ in pairs]
    assert any(not torch.equal(p, t) for p, t in zip(*before[0], strict=True))
    learner.update_targets()
    for (net_p, targ_p), (_, targ) in zip(before, pairs, strict=True):
        for p, t_old, t_new in zip(net_p, targ_p, targ.parameters(), strict=True):
            want = polyak * t_old.double() + (1 - polyak) * p.double()
            torch.testing.assert_close(t_new.double(), want, rtol=1e-6, atol=1e-7)
    assert learner.target_updates == 1


def test_targets_are_copies_at_init_and_do_not_move_with_updates() -> None:
    learner = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    for net, targ in ((learner.actor, learner.actor_target),
                      (learner.critic, learner.critic_target)):
        for p, t in zip(net.parameters(), targ.parameters(), strict=True):
            assert torch.equal(p, t) and p.data_ptr() != t.data_ptr()
    targ_before = _params(learner.critic_target)
    update_losses(learner, _batch(SPEC, 32, seed=3))
    for t_old, t in zip(targ_before, learner.critic_target.parameters(), strict=True):
        assert torch.equal(t_old, t)


@pytest.mark.parametrize("max_action", [1.0, 2.5], ids=["max1", "max2.5"])
def test_actor_output_bounded_by_max_action(max_action: float) -> None:
    spec = dataclasses.replace(SPEC, max_action=max_action)
    actor = Actor(spec=spec, config=SMALL, seed=0)
    with torch.no_grad():
        for p in actor.parameters():
            p.mul_(50.0)  # saturate tanh
        a = actor(1e3 * torch.randn(512, spec.obs_dim + spec.goal_dim,
                                    generator=torch.Generator().manual_seed(1)))
    assert a.shape == (512, spec.action_dim)
    assert a.abs().max().item() <= max_action
    assert a.abs().max().item() > 0.99 * max_action


def test_critic_scales_the_action_by_max_action() -> None:
    spec2 = dataclasses.replace(SPEC, max_action=2.0)
    c1 = Critic(spec=SPEC, config=SMALL, seed=4)
    c2 = Critic(spec=spec2, config=SMALL, seed=4)
    x = torch.randn(8, SPEC.obs_dim + SPEC.goal_dim, generator=torch.Generator().manual_seed(2))
    a = torch.rand(8, SPEC.action_dim, generator=torch.Generator().manual_seed(3)) * 2 - 1
    torch.testing.assert_close(c2(x, 2.0 * a), c1(x, a))


def test_critic_loss_decreases_on_a_fixed_batch() -> None:
    learner = DDPGLearner(spec=SPEC, config=DDPGConfig(), seed=0)
    batch = _batch(SPEC, 256, seed=5)
    losses = [update_losses(learner, batch)["critic_loss"] for _ in range(50)]
    assert losses[-1] < 0.2 * losses[0], losses[::10]
    assert learner.updates == 50


def test_actor_loss_decreases_on_a_fixed_batch() -> None:
    """With the critic fixed by lr_critic≈0, μ climbs Q: L_μ must go down."""
    config = dataclasses.replace(SMALL, lr_critic=1e-12)
    learner = DDPGLearner(spec=SPEC, config=config, seed=0)
    batch = _batch(SPEC, 64, seed=6)
    losses = [update_losses(learner, batch)["actor_loss"] for _ in range(30)]
    assert losses[-1] < losses[0]


def test_update_uses_the_adopted_normalizer_state() -> None:
    batch = _batch(SPEC, 32, seed=7)
    a = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    b = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    o_norm, g_norm = Normalizer(SPEC.obs_dim), Normalizer(SPEC.goal_dim)
    o_norm.update(batch.o * 4 + 2)
    g_norm.update(batch.g + 1)
    o_norm.recompute_stats()
    g_norm.recompute_stats()
    b.set_normalizer_state(o_norm.state_dict(), g_norm.state_dict())
    assert update_losses(a, batch)["critic_loss"] != update_losses(b, batch)["critic_loss"]
    o_state, _ = b.normalizer_state()
    np.testing.assert_array_equal(o_state["mean"], o_norm.mean)


def test_state_dict_round_trip_reproduces_training() -> None:
    src = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    o_norm = Normalizer(SPEC.obs_dim)
    o_norm.update(_batch(SPEC, 64, seed=8).o)
    o_norm.recompute_stats()
    src.set_normalizer_state(o_norm.state_dict(), Normalizer(SPEC.goal_dim).state_dict())
    for i in range(3):
        update_losses(src, _batch(SPEC, 32, seed=20 + i))
    src.update_targets()
    state = src.state_dict()

    dst = DDPGLearner(spec=SPEC, config=SMALL, seed=1)
    dst.load_state_dict(state)
    # training both further gives identical losses and weights (Adam moments restored too)
    for i in range(3):
        batch = _batch(SPEC, 32, seed=30 + i)
        assert update_losses(src, batch) == update_losses(dst, batch)
    src.update_targets()
    dst.update_targets()
    for name in ("actor", "critic", "actor_target", "critic_target"):
        for p, q in zip(getattr(src, name).parameters(), getattr(dst, name).parameters(),
                        strict=True):
            assert torch.equal(p, q), name
    assert (dst.updates, dst.target_updates) == (6, 2)
    # the checkpoint is a snapshot: training afterwards did not change it
    p0 = next(iter(state["actor"].values()))
    assert not torch.equal(p0, next(iter(src.actor.state_dict().values())))


def test_seeded_construction_is_deterministic_and_leaves_global_rng_alone() -> None:
    torch.manual_seed(1234)
    rng_state = torch.random.get_rng_state()
    a = DDPGLearner(spec=SPEC, config=SMALL, seed=42)
    b = DDPGLearner(spec=SPEC, config=SMALL, seed=42)
    c = DDPGLearner(spec=SPEC, config=SMALL, seed=43)
    assert torch.equal(torch.random.get_rng_state(), rng_state)
    for name in ("actor", "critic"):
        pa, pb, pc = (list(getattr(x, name).parameters()) for x in (a, b, c))
        assert all(torch.equal(x, y) for x, y in zip(pa, pb, strict=True)), name
        assert not torch.equal(pa[0], pc[0]), name
    # actor and critic draw from different streams
    assert not torch.equal(a.actor.net[0].weight[:4, :4], a.critic.net[0].weight[:4, :4])


def test_policy_weights_broadcast_reproduces_the_learners_actor() -> None:
    learner = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    o_norm, g_norm = Normalizer(SPEC.obs_dim), Normalizer(SPEC.goal_dim)
    batch = _batch(SPEC, 32, seed=9)
    o_norm.update(batch.o * 2)
    o_norm.recompute_stats()
    learner.set_normalizer_state(o_norm.state_dict(), g_norm.state_dict())
    update_losses(learner, batch)
    w = learner.policy_weights(version=3)
    policy = Policy(spec=SPEC, config=SMALL, seed=99)
    policy.load(w)
    a = policy.act(batch.o, batch.g, explore=False)
    x = preprocess(batch.o, batch.g, learner.o_norm, learner.g_norm, SMALL.clip_obs)
    with torch.no_grad():
        want = learner.actor(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(a, want, rtol=1e-6, atol=1e-7)
    assert policy.version == 3


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [("u", np.zeros((32, 3), np.float32), "'u'"),
     ("r", np.zeros(31, np.float32), "'r'"),
     ("o2", np.zeros((32, 5), np.float32), "'o2'")],
    ids=["wrong-action-dim", "short-reward", "narrow-o2"],
)
def test_update_rejects_malformed_batches(key: str, value: np.ndarray, match: str) -> None:
    learner = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    batch = _batch(SPEC, 32, seed=0)._replace(**{key: value})
    with pytest.raises(ValueError, match=match):
        update_losses(learner, batch)
    assert learner.updates == 0


def test_the_return_clip_follows_the_tasks_rewards(trusted_test_envs: None) -> None:
    """Fetch's −1/0 rewards bound returns to [−1/(1−γ), 0] (the reference's clip);
    PointMaze's 0/1 rewards to [0, 1/(1−γ)]: a Fetch clip there would zero every target."""
    assert return_bounds(task_spec("push"), 0.98) == pytest.approx((-50.0, 0.0))
    assert return_bounds(task_spec("PointMaze_UMaze-v3"), 0.98) == pytest.approx((0.0, 50.0))
    assert task_spec("tests.goal_envs:point_on_a_plane").failure_reward == -1.0


def test_a_batch_checked_on_arrival_is_taken_as_it_is_and_gives_the_same_update() -> None:
    """A served batch is checked once: `decode_minibatch` checks it against the task and
    returns a `CheckedBatch`, which the learner does not check again; a batch handed to
    `update` directly is still checked."""
    from hercs.errors import InvalidMessage
    from hercs.wire.batch import CheckedBatch
    from hercs.wire.codec import minibatch_to_msg
    from hercs.wire.validation import decode_minibatch

    batch = _batch(SPEC, 8, seed=3)
    checked = decode_minibatch(minibatch_to_msg(batch), SPEC, batch_size=8)
    assert isinstance(checked, CheckedBatch)
    learner = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    assert learner._check_batch(checked) is checked
    twin = DDPGLearner(spec=SPEC, config=SMALL, seed=0)
    assert update_losses(learner, checked) == update_losses(twin, batch)
    with pytest.raises(ValueError, match="'u' has shape"):
        update_losses(learner, batch._replace(u=batch.u[:, :2]))
    with pytest.raises(InvalidMessage, match=r"Minibatch\.u"):
        decode_minibatch(minibatch_to_msg(batch._replace(u=batch.u[:, :2])), SPEC, batch_size=8)
