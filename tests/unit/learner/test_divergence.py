"""A learner whose losses or weights stop being finite says where and stops: `Diverged` names
the epoch, the cycle, the update and the value, before anything of that cycle can be
published or saved; a checkpoint is never overwritten with numbers that are not finite."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from hercs.config import HercsConfig, apply_overrides
from hercs.errors import Diverged
from hercs.learner.builder import LearnerBuilder
from hercs.learner.cuda_graph import loss_row
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.evaluations import EvalRequests
from hercs.learner.loop import LearnerLoop
from hercs.learner.resume import save_learner_state
from hercs.rl.normalizer import Normalizer
from hercs.run.rundir import RunDir
from hercs.wire.served import ReplayCounters, ServedBatch
from tests.support import random_transition_batch

HAS_CUDA = torch.cuda.is_available()


def config() -> HercsConfig:
    # no clip of the TD target: a reward of -1e30 then reaches the critic's loss
    return apply_overrides(HercsConfig(), [
        "task.name=reach", "run.method=her", "training.cycles_per_epoch=3",
        "training.minibatches_per_cycle=4", "ddpg.batch_size=16", "ddpg.hidden_size=32",
        "ddpg.clip_return=false"])


def served(cfg: HercsConfig, seed: int, *, reward: float | None = None) -> ServedBatch:
    """One cycle's minibatches; `reward` replaces every reward (a reward gone wild)."""
    spec = cfg.task.spec
    minibatches = []
    for i in range(cfg.training.minibatches_per_cycle):
        batch = random_transition_batch(spec, cfg.ddpg.batch_size, seed=seed * 100 + i)
        if reward is not None:
            batch = batch._replace(r=np.full_like(batch.r, reward))
        minibatches.append(batch)
    return ServedBatch(minibatches=minibatches,
                       o_stats=Normalizer(spec.obs_dim).state_dict(),
                       g_stats=Normalizer(spec.goal_dim).state_dict())


def learner_and_loop(cfg: HercsConfig, device: str = "cpu", **kwargs: bool
                     ) -> tuple[DDPGLearner, LearnerLoop]:
    learner = DDPGLearner(spec=cfg.task.spec, config=cfg.ddpg, seed=0, device=device, **kwargs)
    return learner, LearnerBuilder(cfg).loop(
        learner, replay_status=lambda samples: ReplayCounters(samples=samples))


def target_weights(learner: DDPGLearner) -> list[torch.Tensor]:
    return [p.detach().cpu().clone() for net in (learner.actor_target, learner.critic_target)
            for p in net.parameters()]


def test_a_loss_that_is_not_finite_stops_the_cycle_naming_epoch_cycle_update_and_value(
        ) -> None:
    cfg = config()
    learner, loop = learner_and_loop(cfg)
    for cycle in range(4):  # epoch 1, then the first cycle of epoch 2
        loop.step(served(cfg, cycle))
    targets, version = target_weights(learner), loop.version
    with pytest.raises(Diverged) as err:
        loop.step(served(cfg, 4, reward=-1e30))
    # the second cycle of epoch 2, whose first update (the run's 17th) squared a 1e30 error
    assert str(err.value) == ("training diverged in epoch 2, cycle 2 of 3 (the run's cycle 5), "
                              "update 17: critic_loss = inf")
    assert loop.version == version == 4, "no new weights version to publish"
    assert all(torch.equal(a, b) for a, b in zip(targets, target_weights(learner), strict=True))


def test_a_weight_that_is_not_finite_is_named_before_the_weights_are_published() -> None:
    cfg = config()
    learner, loop = learner_and_loop(cfg)
    loop.step(served(cfg, 0))
    with torch.no_grad():  # what an overflowing Adam step leaves
        next(learner.actor.parameters()).view(-1)[:3] = torch.tensor([np.nan, np.inf, -np.inf])
    name, param = next(iter(learner.actor.named_parameters()))
    with pytest.raises(Diverged) as err:
        learner.check_finite(first_update=learner.updates + 1)
    assert str(err.value) == (f"after update 4: actor.{name} holds 3 non-finite of its "
                              f"{param.numel()} values (-inf, inf, nan)")


class _CapturedOnTheCpu:
    """What a captured CUDA graph does per minibatch (the update, its losses added to the
    sums on the device, nothing read back), run eagerly: the cycle's check must find what the
    per-update check of the eager CPU path would have."""

    def __init__(self, learner: DDPGLearner) -> None:
        self.learner = learner

    def train(self, host: tuple[np.ndarray, ...]) -> None:
        learner = self.learner
        stats = learner.step_tensors(*(torch.from_numpy(a) for a in host))
        learner.loss_sums.add_(loss_row(stats))


def test_the_graphs_path_finds_a_bad_loss_in_the_cycles_sums() -> None:
    cfg = config()
    learner, loop = learner_and_loop(cfg)
    learner._captured = _CapturedOnTheCpu(learner)  # type: ignore[assignment]
    loop.step(served(cfg, 0))
    with pytest.raises(Diverged) as err:
        loop.step(served(cfg, 1, reward=-1e30))
    message = str(err.value)
    assert message.startswith("training diverged in epoch 1, cycle 2 of 3 (the run's cycle 2), "
                              "updates 5-8: critic_loss = inf"), message
    assert message.endswith("(the losses' sums since the epoch began)")
    assert loop.version == 1


@pytest.mark.skipif(not HAS_CUDA, reason="no CUDA device here: the captured update is not run")
def test_a_captured_update_on_a_gpu_is_checked_once_per_cycle() -> None:
    cfg = config()
    learner, loop = learner_and_loop(cfg, device="cuda", cuda_graph=True)
    loop.step(served(cfg, 0))
    assert learner._captured is not None and learner._captured.graph is not None
    with pytest.raises(Diverged, match=r"cycle 2 of 3 .*, updates 5-8: critic_loss = inf"):
        loop.step(served(cfg, 1, reward=-1e30))


def test_a_checkpoint_is_never_overwritten_with_numbers_that_are_not_finite(
        tmp_path: Path) -> None:
    """Adam's second moment can overflow to inf while every weight stays finite (that weight
    then never moves again): the whole state is checked, and the previous file kept."""
    cfg = config()
    learner, loop = learner_and_loop(cfg)
    for cycle in range(3):
        loop.step(served(cfg, cycle))
    folder = RunDir(tmp_path).checkpoints

    def save() -> bool:
        return save_learner_state(folder, learner=learner, loop=loop,
                                  eval_requests=EvalRequests(resend_s=60.0),
                                  config_record=cfg.to_dict())

    assert save()
    sound = (folder / "learner.pt").read_bytes()
    state = next(iter(learner.critic_optim.state.values()))
    state["exp_avg_sq"].view(-1)[0] = float("inf")
    with pytest.raises(Diverged, match=r"learner\.pt not written, the one there is kept: "
                                       r"learner\.critic_optim\.state\.\d+\.exp_avg_sq holds 1 "
                                       r"non-finite of its \d+ values \(inf\)"):
        save()
    assert (folder / "learner.pt").read_bytes() == sound
    assert not (folder / "learner.pt.tmp").exists()


def test_finite_updates_pass_every_check() -> None:
    cfg = config()
    learner, loop = learner_and_loop(cfg)
    for cycle in range(3):
        loop.step(served(cfg, cycle))
    assert loop.epoch == 1 and learner.updates == 12
    assert np.isfinite(loop.pending[1].losses["critic_loss"])
