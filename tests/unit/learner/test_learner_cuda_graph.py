"""learner.cuda_graph: the captured update against the eager GPU update (where a GPU exists),
and a CPU learner that ignores the setting."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hercs.config import DDPGConfig
from hercs.learner.cuda_graph import CaptureFailed
from hercs.learner.ddpg import DDPGLearner
from hercs.rl.task_registry import task_spec
from tests.support import random_transition_batch

SPEC = task_spec("push")
CONFIG = DDPGConfig(batch_size=64)
HAS_CUDA = torch.cuda.is_available()
NO_CUDA = "no CUDA device here (torch.cuda.is_available() is False): the captured update is not run"


def _train(learner: DDPGLearner, updates: int, first_seed: int = 0) -> dict[str, float]:
    for i in range(updates):
        learner.train(random_transition_batch(SPEC, CONFIG.batch_size, seed=first_seed + i))
        if i % 10 == 9:
            learner.update_targets()
    return learner.loss_means()


def test_a_cpu_learner_ignores_the_setting() -> None:
    learner = DDPGLearner(spec=SPEC, config=CONFIG, seed=0, cuda_graph=True)
    assert learner._captured is None
    assert np.isfinite(_train(learner, 2)["critic_loss"])


class _Uncapturable:
    def train(self, host: object) -> None:
        raise CaptureFailed("RuntimeError: operation not permitted when stream is capturing")


def test_a_failed_capture_falls_back_to_the_eager_update_and_says_so(
        caplog: pytest.LogCaptureFixture) -> None:
    """A torch, GPU or driver that cannot capture must not stop a run: the capture undoes its
    warm-up and raises CaptureFailed, and the learner goes on eagerly (driven here on the CPU
    with a stand-in capture that fails)."""
    plain = DDPGLearner(spec=SPEC, config=CONFIG, seed=6)
    falling = DDPGLearner(spec=SPEC, config=CONFIG, seed=6)
    falling._captured = _Uncapturable()  # type: ignore[assignment]
    with caplog.at_level("WARNING", logger="hercs.learner.ddpg"):
        assert _train(falling, 5) == _train(plain, 5)
    assert falling._captured is None and falling.updates == 5
    assert [r.getMessage() for r in caplog.records if "could not be captured" in
            r.getMessage()] != []


@pytest.mark.skipif(not HAS_CUDA, reason=NO_CUDA)
@pytest.mark.parametrize("precision", ["fp32", "bf16", "tf32"])
def test_the_captured_update_matches_the_eager_one(precision: str) -> None:
    eager = DDPGLearner(spec=SPEC, config=CONFIG, seed=2, device="cuda", precision=precision)
    graph = DDPGLearner(spec=SPEC, config=CONFIG, seed=2, device="cuda", precision=precision,
                        cuda_graph=True)
    assert graph._captured is not None
    want, got = _train(eager, 30), _train(graph, 30)
    tolerance = 1e-2 if precision == "bf16" else 1e-4
    for key in want:
        assert got[key] == pytest.approx(want[key], rel=tolerance, abs=tolerance), key
    for name, array in eager.actor_weights().items():
        np.testing.assert_allclose(graph.actor_weights()[name], array, atol=10 * tolerance)
    assert graph.updates == eager.updates == 30
    assert graph._captured is not None  # the graph ran: no fallback to the eager update


@pytest.mark.skipif(not HAS_CUDA, reason=NO_CUDA)
def test_a_checkpoint_loaded_into_a_captured_learner_is_recaptured_and_continues() -> None:
    source = DDPGLearner(spec=SPEC, config=CONFIG, seed=3, device="cuda", cuda_graph=True)
    _train(source, 15)
    state = source.state_dict()
    eager = DDPGLearner(spec=SPEC, config=CONFIG, seed=9, device="cuda")
    eager.load_state_dict(state)
    graph = DDPGLearner(spec=SPEC, config=CONFIG, seed=9, device="cuda", cuda_graph=True)
    _train(graph, 2)  # captured before the load: the load must recapture
    graph.load_state_dict(state)
    want, got = _train(eager, 10, first_seed=100), _train(graph, 10, first_seed=100)
    for key in want:
        assert got[key] == pytest.approx(want[key], rel=1e-4, abs=1e-4), key
    assert graph._captured is not None  # recaptured, not fallen back to the eager update
    assert graph._captured.graph is not None and not graph.loss_sums.requires_grad
