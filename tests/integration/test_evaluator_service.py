"""`hercs evaluator` as a real process against a router on loopback.

The test plays the learner: it publishes `Weights` (latest kept, as the learner does) and
listens to `eval/result`. No sleeps stand in for synchronisation: every wait is on a queue
with a timeout or the process exit.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.policy import Policy
from hercs.transport import Transport
from proto import SCHEMA_VERSION
from proto import hercs_pb2 as pb
from proto.codec import arrays_to_named, stats_to_msg
from proto.keys import RunKeys

pytestmark = pytest.mark.integration

WAIT_S = 15.0
STOP_WITHIN_S = 5.0

OpenClient = Callable[[], Transport]


# ---- process helpers (the same in the actor and evaluator tests)


def start_service(role: str, config: HercsConfig, ident: str, tmp_path: Path) -> subprocess.Popen:
    path = tmp_path / f"{role}.yaml"
    save_yaml(config, path)
    with (tmp_path / f"{role}.log").open("w") as log:  # the child keeps its own copy
        return subprocess.Popen(
            [sys.executable, "-m", "hercs.cli", role, "--config", str(path), "--id", ident],
            stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "HERCS_LOG": "INFO"},
        )


def wait_for(q: queue.Queue, pred: Callable[[object], bool], what: str) -> object:
    """The first item of `q` satisfying `pred` (others are discarded), within WAIT_S."""
    deadline = time.monotonic() + WAIT_S
    while True:
        try:
            item = q.get(timeout=max(deadline - time.monotonic(), 0.001))
        except queue.Empty:
            raise AssertionError(f"timed out after {WAIT_S} s waiting for {what}") from None
        if pred(item):
            return item


def sigterm_exits_cleanly(proc: subprocess.Popen, alive: queue.Queue, key: str) -> None:
    started = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=STOP_WITHIN_S + 5) == 0
    assert time.monotonic() - started < STOP_WITHIN_S
    wait_for(alive, lambda c: c == (key, False), f"{key} to vanish")


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[list[subprocess.Popen]]:
    started: list[subprocess.Popen] = []
    yield started
    for proc in started:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    for log in tmp_path.glob("*.log"):  # shown by pytest on failure
        print(f"---- {log.name}\n{log.read_text()}")


# ---- the evaluator


def tiny_config(endpoint: str) -> HercsConfig:
    return apply_overrides(HercsConfig(), [
        "run.name=t-evaluator", "run.method=her", "task.name=reach", "training.eval_episodes=5",
        "ddpg.hidden_size=64", f"transport.connect=[{endpoint}]",
    ])


def weights_msg(policy: Policy, *, version: int, epoch: int, evaluate: bool) -> bytes:
    """A `Weights` message as the learner broadcasts it."""
    w = policy.weights()
    return pb.Weights(
        schema_version=SCHEMA_VERSION, version=version, epoch=epoch, evaluate=evaluate,
        actor_params=arrays_to_named(w.actor), o_stats=stats_to_msg(w.o_stats),
        g_stats=stats_to_msg(w.g_stats),
    ).SerializeToString()


def test_evaluator_answers_every_eval_epoch_and_nothing_else(
    open_client: OpenClient, endpoint: str, tmp_path: Path, procs: list[subprocess.Popen],
) -> None:
    config = tiny_config(endpoint)
    keys = RunKeys(config.run.name)
    learner = open_client()
    alive: queue.Queue = queue.Queue()
    learner.watch_alive(keys.all_alive, lambda key, up: alive.put((key, up)))
    results: queue.Queue[pb.EvalResult] = queue.Queue()
    learner.subscribe(keys.eval_result, lambda key, raw: results.put(pb.EvalResult.FromString(raw)))
    metrics: queue.Queue[dict[str, float]] = queue.Queue()
    learner.subscribe(keys.metrics("evaluator"),
                      lambda key, raw: metrics.put(dict(pb.Metrics.FromString(raw).values)))
    weights = learner.publisher(keys.weights, latest=True)
    policy = Policy(spec=config.task.spec, config=config.ddpg, seed=3)

    procs.append(start_service("evaluator", config, "e0", tmp_path))
    wait_for(alive, lambda c: c == (keys.alive("evaluator", "e0"), True), "the evaluator")
    wait_for(metrics, lambda m: True, "the evaluator's first metrics (it has subscribed)")

    weights.put(weights_msg(policy, version=1, epoch=0, evaluate=False))
    weights.put(b"\x08\x01 not a Weights message")
    weights.put(weights_msg(policy, version=2, epoch=1, evaluate=True))
    first = results.get(timeout=WAIT_S)
    assert (first.epoch, first.weights_version) == (1, 2)
    assert first.episodes == config.training.eval_episodes
    assert 0.0 <= first.success_rate <= 1.0
    assert first.success_rate * first.episodes == pytest.approx(round(first.success_rate
                                                                      * first.episodes))
    assert np.isfinite(first.mean_final_distance) and first.mean_final_distance >= 0.0

    # Newer non-eval weights arriving during an evaluation must not displace a queued one.
    for version, epoch, evaluate in [(3, 2, True), (4, 2, False), (5, 3, True), (6, 3, False),
                                     (7, 4, True)]:
        weights.put(weights_msg(policy, version=version, epoch=epoch, evaluate=evaluate))
    later = [results.get(timeout=WAIT_S) for _ in range(3)]
    assert [(r.epoch, r.weights_version) for r in later] == [(2, 3), (3, 5), (4, 7)]
    assert all(r.episodes == config.training.eval_episodes for r in later)
    assert results.empty(), "a Weights with evaluate=False produced a result"
    # The same policy on fresh goals from one seeded stream: results are plausible, not equal.
    assert all(0.0 <= r.success_rate <= 1.0 for r in later)

    sigterm_exits_cleanly(procs[0], alive, keys.alive("evaluator", "e0"))
