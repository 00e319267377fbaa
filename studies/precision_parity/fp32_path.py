"""The fp32 learner path of one source tree, as numbers: N DDPG updates from fixed batches.

The parity study's fp32 arm may be runs trained at earlier commits than its bf16 arm; that
holds only if those commits' fp32 learners do the same arithmetic. `python -m
studies.precision_parity.fp32_path --out F.npz` builds this tree's FetchPush learner from its
own default config (as `hercs up` would), feeds it `--cycles` cycles of `--updates` seeded
random minibatches of 256 with a Polyak step after each cycle, and saves the actor's, the
critic's and their targets' parameters. Run with another commit's tree first on PYTHONPATH,
it imports that tree's learner: the layout has moved (learner/ddpg.py, then
hercs/learner/ddpg.py; `update`, then `train`), and each is looked up where it was.
`load` reads such a file and `compare` two (tests/studies/precision_parity/test_fp32_path.py).
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path
from typing import Any

import numpy as np

BATCH = 256


def _first_module(*names: str) -> Any:
    """The first of `names` that this tree holds. An editable install of another tree can
    still answer for a subpackage the tree lacks (its finder extends `hercs.__path__`), so a
    module from outside the tree counts as absent."""
    import hercs

    tree = Path(hercs.__file__).resolve().parent.parent
    for name in names:
        try:
            module = importlib.import_module(name)
        except ImportError:  # ModuleNotFoundError, or a module of the wrong tree's
            continue
        if Path(str(module.__file__)).resolve().is_relative_to(tree):
            return module
    raise ModuleNotFoundError(f"none of {', '.join(names)} in the tree at {tree}")


def build_learner() -> Any:
    """This tree's learner as its `hercs up` builds it for FetchPush (its defaults, fp32)."""
    from hercs.config import HercsConfig, apply_overrides

    config = apply_overrides(HercsConfig(), ["task.name=push", "learner.precision=fp32"])
    try:
        builder = _first_module("hercs.learner.builder")
    except ModuleNotFoundError:  # before the builders: the shell made it from the sections
        ddpg = _first_module("hercs.learner.ddpg", "learner.ddpg")
        return ddpg.DDPGLearner(spec=config.task.spec, config=config.ddpg, seed=config.run.seed)
    return builder.LearnerBuilder(config).learner()


def batches(spec: Any, *, count: int, seed: int) -> list[tuple[np.ndarray, ...]]:
    """`count` minibatches (o, g, u, r, o2) of FetchPush's sizes, float32, from `seed`."""
    rng = np.random.default_rng(seed)
    out: list[tuple[np.ndarray, ...]] = []
    for _ in range(count):
        o = rng.normal(0.0, 1.0, (BATCH, spec.obs_dim)).astype(np.float32)
        g = rng.normal(0.0, 0.2, (BATCH, spec.goal_dim)).astype(np.float32)
        u = rng.uniform(-1.0, 1.0, (BATCH, spec.action_dim)).astype(np.float32)
        r = -(rng.random(BATCH) < 0.8).astype(np.float32)
        o2 = (o + rng.normal(0.0, 0.05, o.shape)).astype(np.float32)
        out.append((o, g, u, r, o2))
    return out


def run(*, cycles: int, updates: int, seed: int) -> dict[str, np.ndarray]:
    """The parameters after `cycles` x `updates` updates, keyed net/parameter in order."""
    learner = build_learner()
    batch_type = _first_module("hercs.wire.batch", "hercs.batch").TransitionBatch
    step = getattr(learner, "train", None) or learner.update
    for cycle in range(cycles):
        for arrays in batches(learner.spec, count=updates, seed=seed * 1000 + cycle):
            step(batch_type(*arrays))
        learner.update_targets()
    params = {}
    for name in ("actor", "critic", "actor_target", "critic_target"):
        for i, p in enumerate(getattr(learner, name).parameters()):
            params[f"{name}/{i}"] = p.detach().cpu().numpy().copy()
    return params


def load(path: Path) -> dict[str, np.ndarray]:
    """A file of `main`'s: the parameters by name."""
    with np.load(path) as saved:
        names = [str(n) for n in saved["names"]]
        return {name: saved[f"arr_{i}"] for i, name in enumerate(names)}


def compare(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> tuple[bool, float]:
    """(bitwise equal, the largest |a - b| relative to the largest |a|) over every parameter."""
    if a.keys() != b.keys():
        raise ValueError(f"different parameters: {sorted(a.keys() ^ b.keys())}")
    equal = all(np.array_equal(a[k], b[k]) for k in a)
    scale = max(float(np.abs(a[k]).max()) for k in a)
    worst = max(float(np.abs(a[k] - b[k]).max()) for k in a)
    return equal, worst / scale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.precision_parity.fp32_path")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--cycles", type=int, default=4)
    parser.add_argument("--updates", type=int, default=25)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    params = run(cycles=args.cycles, updates=args.updates, seed=args.seed)
    np.savez(args.out, *params.values(), names=np.array(list(params)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
