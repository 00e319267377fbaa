"""The stacked learner's contract (issue 56): in fp32 a slot is the same experiment as a lone
`DDPGLearner`. The same batches fed to K lone learners and to a stack of them leave the same
weights, targets, Adam moments and losses within float tolerance; a slot written back is a
lone learner's checkpoint; a learner of another age joins with its own Adam step count; and a
slot whose update turns non-finite leaves the other slots as they would have been."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hercs.config import HercsConfig, apply_overrides
from hercs.learner.ddpg import LOSS_NAMES, DDPGLearner
from hercs.learner.stacked import StackedDDPG, stacked_inputs
from hercs.rl.normalizer import Normalizer
from hercs.wire.batch import TransitionBatch
from tests.support import random_transition_batch

B, K = 32, 3
RTOL, ATOL = 1e-4, 1e-6
"""fp32 batched GEMMs round differently from lone ones; after tens of Adam steps the
differences stay at float noise."""


def config() -> HercsConfig:
    return apply_overrides(HercsConfig(), ["task.name=push", "ddpg.hidden_size=64"])


def lone(cfg: HercsConfig, seed: int) -> DDPGLearner:
    learner = DDPGLearner(spec=cfg.task.spec, config=cfg.ddpg, seed=seed)
    rng = np.random.default_rng(seed)
    spec = cfg.task.spec
    o_norm, g_norm = Normalizer(spec.obs_dim), Normalizer(spec.goal_dim)
    o_norm.update(rng.normal(size=(50, spec.obs_dim)))
    g_norm.update(rng.normal(size=(50, spec.goal_dim)))
    learner.set_normalizer_state(o_norm.state_dict(), g_norm.state_dict())  # its own stats
    return learner


def batches(cfg: HercsConfig, slot: int, n: int) -> list[TransitionBatch]:
    return [random_transition_batch(cfg.task.spec, B, seed=1000 * slot + i) for i in range(n)]


def train_lone(learner: DDPGLearner, data: list[TransitionBatch], every: int) -> None:
    for i, batch in enumerate(data, 1):
        learner.train(batch)
        if i % every == 0:
            learner.update_targets()


def train_stack(stack: StackedDDPG, learners: list[DDPGLearner],
                data: list[list[TransitionBatch]], every: int) -> torch.Tensor:
    losses = torch.zeros(stack.slots, len(LOSS_NAMES), dtype=torch.float64)
    for i, step in enumerate(zip(*data, strict=True), 1):
        losses += stack.train(*stacked_inputs(learners, step))
        if i % every == 0:
            stack.update_targets()
    return losses / len(data[0])


def assert_same_state(got: dict, want: dict) -> None:
    for name in ("actor", "critic", "actor_target", "critic_target"):
        for key, value in want[name].items():
            torch.testing.assert_close(got[name][key], value, rtol=RTOL, atol=ATOL,
                                       msg=lambda m, n=name, k=key: f"{n}.{k}: {m}")
    for name in ("actor_optim", "critic_optim"):
        for index, entry in want[name]["state"].items():
            mine = got[name]["state"][index]
            assert float(mine["step"]) == float(entry["step"]), (name, index)
            for moment in ("exp_avg", "exp_avg_sq"):
                torch.testing.assert_close(mine[moment], entry[moment], rtol=1e-3, atol=1e-8,
                                           msg=lambda m, n=name, i=index, w=moment:
                                           f"{n}[{i}].{w}: {m}")


def written_back(stack: StackedDDPG, k: int, cfg: HercsConfig, template: DDPGLearner
                 ) -> dict:
    """Slot k stored into a learner that was `template` (its normalisers, counters)."""
    out = DDPGLearner(spec=cfg.task.spec, config=cfg.ddpg, seed=99)
    out.load_state_dict(template.state_dict())
    stack.store_learner(k, out)
    return out.state_dict()


def test_k_slots_end_where_k_lone_learners_end_on_the_same_batches() -> None:
    cfg = config()
    seeds = [11, 12, 13]
    data = [batches(cfg, k, 24) for k in range(K)]
    alone = [lone(cfg, s) for s in seeds]
    stacked = [lone(cfg, s) for s in seeds]
    stack = StackedDDPG(spec=cfg.task.spec, config=cfg.ddpg, learners=stacked)
    for learner, d in zip(alone, data, strict=True):
        train_lone(learner, d, every=8)
    means = train_stack(stack, stacked, data, every=8)
    for k, learner in enumerate(alone):
        assert_same_state(written_back(stack, k, cfg, stacked[k]), learner.state_dict())
        expected = learner.loss_means()
        for j, name in enumerate(LOSS_NAMES):
            assert means[k, j].item() == pytest.approx(expected[name], rel=1e-4, abs=1e-6), name
    # the slots really are different experiments: different seeds, different weights
    first, second = (written_back(stack, k, cfg, stacked[k])["actor"]["net.0.weight"]
                     for k in (0, 1))
    assert not torch.allclose(first, second)


def test_a_slot_written_back_resumes_alone_and_a_learner_of_another_age_joins() -> None:
    """Slot 0 trained in the stack, written back and trained on alone, ends where a learner
    trained alone throughout ends; a learner that already has 10 updates joins a fresh one's
    stack with its own Adam step count (bias correction), and both end as alone."""
    cfg = config()
    older, younger = lone(cfg, 21), lone(cfg, 22)
    train_lone(older, batches(cfg, 5, 10), every=5)
    reference = [lone(cfg, 21), lone(cfg, 22)]
    reference[0].load_state_dict(older.state_dict())
    stack = StackedDDPG(spec=cfg.task.spec, config=cfg.ddpg, learners=[older, younger])
    data = [batches(cfg, 6, 12), batches(cfg, 7, 12)]
    train_stack(stack, [older, younger], data, every=4)
    for learner, d in zip(reference, data, strict=True):
        train_lone(learner, d[:8], every=4)
    resumed = [DDPGLearner(spec=cfg.task.spec, config=cfg.ddpg, seed=0) for _ in range(2)]
    for k, learner in enumerate(resumed):
        learner.load_state_dict(written_back(stack, k, cfg, [older, younger][k]))
    assert [float(s) for s in stack.actor_optim.steps] == [22.0, 12.0]
    # the stack went 4 updates further than the references: take those alone too
    for learner, d in zip(reference, data, strict=True):
        train_lone(learner, d[8:], every=4)
    for k in range(2):
        assert_same_state(resumed[k].state_dict(), reference[k].state_dict())


def test_a_slot_whose_update_turns_non_finite_leaves_the_others_as_they_would_be() -> None:
    cfg = config()
    alone = lone(cfg, 31)
    stacked = [lone(cfg, 31), lone(cfg, 32)]
    stack = StackedDDPG(spec=cfg.task.spec, config=cfg.ddpg, learners=stacked)
    good = batches(cfg, 8, 6)
    bad = [b._replace(r=np.full_like(b.r, np.nan)) for b in batches(cfg, 9, 6)]
    train_lone(alone, good, every=3)
    means = train_stack(stack, stacked, [good, bad], every=3)
    assert np.isnan(means[1, 0].item()), "slot 1's loss says it diverged"
    assert_same_state(written_back(stack, 0, cfg, stacked[0]), alone.state_dict())


def test_bf16_slots_stay_near_their_fp32_selves() -> None:
    """bf16 autocast of the online passes (fp32 master weights and Adam): not the same
    experiment (its learning is the parity study's to measure), but the same update within
    bf16's ~3 significant digits over a few steps."""
    cfg = config()
    learners = [lone(cfg, 41), lone(cfg, 42)]
    data = [batches(cfg, 10, 4), batches(cfg, 11, 4)]
    fp32 = StackedDDPG(spec=cfg.task.spec, config=cfg.ddpg, learners=learners)
    bf16 = StackedDDPG(spec=cfg.task.spec, config=cfg.ddpg, learners=learners,
                       precision="bf16")
    a, b = (train_stack(s, learners, data, every=2) for s in (fp32, bf16))
    assert torch.isfinite(b).all()
    torch.testing.assert_close(b[:, 0], a[:, 0], rtol=0.05, atol=1e-3)
    for p, q in zip(fp32.actor.parameters(), bf16.actor.parameters(), strict=True):
        torch.testing.assert_close(q, p, rtol=0.05, atol=5e-3)


def test_an_empty_stack_or_an_unknown_precision_is_refused() -> None:
    cfg = config()
    with pytest.raises(ValueError, match="no learners"):
        StackedDDPG(spec=cfg.task.spec, config=cfg.ddpg, learners=[])
    with pytest.raises(ValueError, match="precision 'tf32'"):
        StackedDDPG(spec=cfg.task.spec, config=cfg.ddpg, learners=[lone(cfg, 1)],
                    precision="tf32")
