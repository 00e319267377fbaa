"""The three fuzzed runs: their names, keys, configs and the limits the barrages keep to."""

from __future__ import annotations

import re
from pathlib import Path

from hypothesis import HealthCheck, Phase, settings
from hypothesis import strategies as st

from hercs.config import HercsConfig, apply_overrides
from hercs.proto.keys import RunKeys

RUN_R, RUN_A, RUN_L = "fz-replay", "fz-actor", "fz-learner"
KR, KA, KL = RunKeys(RUN_R), RunKeys(RUN_A), RunKeys(RUN_L)
MAX_BYTES = 64 * 1024
"""`replay.max_message_bytes` of the runs (the default is 8 MiB; a small limit makes oversized
payloads cheap)."""
HEADER_MAX_BYTES = 64 * 1024  # hercs.clusterer.clusterer_shell._HEADER_MAX_BYTES
LEARNER_EVAL_MAX_BYTES = 1 << 20  # hercs.learner.learner_shell: EvalResult and ReplayStatus
REQUEST_TIMEOUT_S = 15.0
WAIT_S = 30.0
ACK_EVERY_S = 0.05
VALID_BATCH_EVERY_S = 0.1
K = 4
LEARNER_B, LEARNER_N = 8, 2
CYCLES_PER_EPOCH = 2
MAX_VALID_SAMPLE_ROWS = 4096
"""A valid SampleRequest for more transitions is not sent (it is valid and only costs time)."""
MAX_VALID_BATCHES = 16
"""Valid Batch replies (most are bit flips in a float) the learner may be sent: each costs a
training cycle, which is all a valid one tests; the rest are not sent."""
MAX_VALID_HEADERS = 60
"""Valid headers the clusterer may be sent: its buffer (cluster.fgb_size) must not fill, or
it would refit and publish a model of its own to the replay."""
VALID = "valid"
"""An oracle's verdict for a payload the service takes (stores, adopts, answers)."""
LOG_PROBLEMS = re.compile(r"Traceback|thread \S+ died|raised; |on_error for")

SEEDS = st.integers(0, 2**32 - 1)
HYPOTHESIS = settings(deadline=None, database=None, derandomize=True,
                      suppress_health_check=list(HealthCheck),
                      phases=[Phase.explicit, Phase.generate])
"""The parent of every barrage's settings. Shrinking is off: the services keep state between
examples, and a failing example is printed as generated (each `Probe` names how it was
made)."""


# --------------------------------------------------------------------------- configs

def replay_config(endpoint: str, run_dir: Path) -> HercsConfig:
    return apply_overrides(HercsConfig(), [
        f"run.name={RUN_R}", f"run.run_dir={run_dir}", "run.method=her-cs", "task.name=reach",
        # the paper's 256 units make weights over MAX_BYTES, which the config refuses
        "ddpg.hidden_size=32", f"cluster.k={K}", "cluster.fgb_size=2000", "cluster.kmeans_n_init=1",
        "replay.free_run=true", "replay.min_episodes_to_sample=4",
        # the probes' episodes carry any weights version: the lag bound (not input
        # validation) would refuse some of the valid ones
        "training.max_policy_lag=-1",
        f"replay.max_message_bytes={MAX_BYTES}", f"transport.connect=[{endpoint}]",
    ])


def actor_config(endpoint: str, run_dir: Path) -> HercsConfig:
    """What the test, playing the replay, serves to the actor; the evaluator's own file."""
    return apply_overrides(HercsConfig(), [
        f"run.name={RUN_A}", f"run.run_dir={run_dir}", "run.method=her", "task.name=reach",
        "ddpg.hidden_size=32", "actor.insert_timeout_s=120", "training.eval_episodes=1",
        f"replay.max_message_bytes={MAX_BYTES}", f"transport.connect=[{endpoint}]",
    ])


def learner_config(endpoint: str, run_dir: Path) -> HercsConfig:
    return apply_overrides(HercsConfig(), [
        f"run.name={RUN_L}", f"run.run_dir={run_dir}", "run.method=her", "task.name=reach",
        "ddpg.hidden_size=32", f"ddpg.batch_size={LEARNER_B}",
        f"training.minibatches_per_cycle={LEARNER_N}",
        f"training.cycles_per_epoch={CYCLES_PER_EPOCH}", "training.epochs=100000",
        f"cluster.k={K}", "replay.sample_timeout_s=120", f"transport.connect=[{endpoint}]",
    ])


_NO_ENDPOINT = "tcp/127.0.0.1:1"
SPEC = replay_config(_NO_ENDPOINT, Path("/nonexistent")).task.spec  # reach, for all three runs
ACTOR_CONFIG = actor_config(_NO_ENDPOINT, Path("/nonexistent"))
LEARNER_CONFIG = learner_config(_NO_ENDPOINT, Path("/nonexistent"))
