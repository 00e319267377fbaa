"""Reading a run's trained policy back from its checkpoints, with no service running: what
`hercs eval` and `hercs.load_policy` share.

A policy file (`best.pt`, `epoch-NNNN.pt`) holds the `Weights` the evaluator received, decoded
here as the evaluator decodes it, so the policy acts exactly as the evaluator's did; from
`learner.pt` the actor and normalisers come from the DDPG state, the config from config.yaml.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hercs.config import HercsConfig, load_yaml
from hercs.errors import ConfigError, InvalidMessage
from hercs.rl.policy import Policy, PolicyWeights
from hercs.run.checkpoint_file import CheckpointError, read_checkpoint_file
from hercs.run.rundir import (
    CONFIG,
    RunDir,
    checkpoint_path,
    missing_checkpoint,
    require_run_dir,
)


@dataclass
class LoadedPolicy:
    """A checkpoint's policy with the config of its run."""

    config: HercsConfig
    epoch: int
    """The epoch whose end the weights are from."""
    source: Path
    """The checkpoint file read."""
    weights: PolicyWeights
    """Actor parameters and normaliser statistics, checked to load into `policy()`."""

    def policy(self) -> Policy:
        """A fresh `Policy` of the run's task holding these weights (act with
        `explore=False` for the evaluator's deterministic actions)."""
        policy = Policy(spec=self.config.task.spec, config=self.config.ddpg, seed=0)
        policy.load(self.weights)
        return policy


def read_policy(run_dir: str | os.PathLike[str], checkpoint: str | None = "best"
                ) -> LoadedPolicy:
    """The policy of `run_dir`'s checkpoint: 'best', 'latest', 'epoch-N' or a .pt file's
    path (None: best if present, else latest, as `hercs eval` does). Raises `RunDirError`
    for a folder that is not a run or a checkpoint that does not exist (naming those that
    do), `CheckpointError` for a file that does not load."""
    run_dir = Path(run_dir)
    path = checkpoint_path(run_dir, checkpoint)
    if not path.is_file():
        if path.parent == RunDir(run_dir).checkpoints:
            require_run_dir(run_dir)  # a folder that is no run: say that first
        raise missing_checkpoint(run_dir, checkpoint, path)
    state = read_checkpoint_file(path, what="checkpoint")
    if not ("policy" in state or "learner" in state):
        raise CheckpointError(f"{path}: neither a policy file (best.pt, epoch-N.pt) nor a "
                              "learner checkpoint (learner.pt) of this version of hercs")
    try:
        config, epoch, weights = _contents(state, run_dir, path)
    except ConfigError as exc:  # a config that does not hold, or names code (code_names)
        raise ConfigError(f"{path}: {exc}") from None
    except (KeyError, TypeError, AttributeError, ValueError) as exc:  # well-formed data only
        raise CheckpointError(f"{path}: does not hold what a checkpoint of this version of "
                              f"hercs holds ({type(exc).__name__}: {exc})") from None
    loaded = LoadedPolicy(config=config, epoch=epoch, source=path, weights=weights)
    try:
        loaded.policy()
    except ValueError as exc:
        raise CheckpointError(f"{path}: the policy in it does not fit task "
                              f"{config.task.name} ({exc})") from None
    return loaded


def _contents(state: dict[str, Any], run_dir: Path, path: Path
              ) -> tuple[HercsConfig, int, PolicyWeights]:
    """The config, epoch and weights a policy file or a learner checkpoint holds."""
    config = HercsConfig.from_dict(state["config"]) if "config" in state else \
        _run_config(run_dir, path)
    if "policy" in state:
        raw = state["policy"]
        if not isinstance(raw, bytes):  # bytes(n) of a number would allocate n bytes
            raise TypeError(f"'policy' is of type {type(raw).__name__}, not the Weights "
                            "message's bytes")
        return config, int(state["epoch"]), _decode_weights(
            raw, max_bytes=config.replay.max_message_bytes, path=path)
    learner, loop = state["learner"], state["loop"]
    weights = PolicyWeights(version=int(loop.get("version", 0)),
                            actor={k: v.detach().cpu().numpy().astype(np.float32)
                                   for k, v in learner["actor"].items()},
                            o_stats=learner["o_norm"], g_stats=learner["g_norm"])
    return config, int(loop["epoch"]), weights


def _decode_weights(raw: bytes, *, max_bytes: int, path: Path) -> PolicyWeights:
    """A policy file's `Weights` bytes as the evaluator decodes them (a message of at most
    `max_bytes`, the run's `replay.max_message_bytes`)."""
    from hercs.proto import hercs_pb2 as pb
    from hercs.wire.codec import msg_to_weight_arrays
    from hercs.wire.validation import parse_message

    try:
        msg = parse_message(raw, pb.Weights, max_bytes=max_bytes)
        actor, o_stats, g_stats = msg_to_weight_arrays(msg)
    except InvalidMessage as exc:
        raise CheckpointError(f"{path}: the policy in it does not load ({exc})") from None
    return PolicyWeights(version=int(msg.version), actor=actor, o_stats=o_stats,
                         g_stats=g_stats)


def _run_config(run_dir: Path, source: Path) -> HercsConfig:
    saved = RunDir(run_dir).config
    if not saved.is_file():
        raise CheckpointError(f"{source}: a learner checkpoint holds no config, and {run_dir} "
                              f"has no {CONFIG} to read it from; give the run directory that "
                              "`hercs up` made")
    try:
        return load_yaml(saved)
    except ConfigError as exc:
        raise CheckpointError(f"{source}: the run's config does not load: {exc}") from None

