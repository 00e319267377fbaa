"""What each sampler feeds the learner: the mix of episodes HER and HER-CS draw from one buffer.

    python -m studies.sampler_mix runs/push-her-cs-s1 [--every-epochs 10] [--minibatches 200]

Replays a run's episode log into a `ReplayTable` and compares each sampler's draws with the
buffer, without training. Needs the whole log (docs/GUIDE.md on `replay.log_max_bytes`)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hercs.config import apply_overrides, load_yaml
from hercs.proto import hercs_pb2 as pb
from hercs.replay_service.builder import ReplayBuilder
from hercs.replay_service.table import ReplayTable
from hercs.rl.methods import make_sampler
from hercs.rl.samplers.base import SamplerSettings
from hercs.run.rundir import RunDir
from hercs.run.runlog import (
    TOPIC_CLUSTER_MODEL,
    TOPIC_EPISODES,
    read_messages,
)
from hercs.wire.codec import msg_to_cluster_model, msg_to_episode

BATCH = 256


def episode_mix(table: ReplayTable, slots: np.ndarray, *, moved_m: float) -> tuple[float, float]:
    """(share of `slots` whose object moved more than moved_m, share that succeeded)."""
    ag = table.store.ag[slots]
    moved = np.linalg.norm(ag[:, -1] - ag[:, 0], axis=-1) > moved_m
    return float(moved.mean()), float(table.store.success[slots].mean())


def effective_share(slots: np.ndarray, size: int) -> float:
    """Effective number of distinct episodes in the draw, (Σc)² / Σc² over per-episode
    counts c, as a share of the expected value for a uniform draw of the same size."""
    counts = np.bincount(slots, minlength=size).astype(np.float64)
    n = len(slots)
    uniform = n * n / (n + n * (n - 1) / size)  # E[Σc²] = n + n(n−1)/size for uniform draws
    return float(counts.sum() ** 2 / (counts**2).sum() / uniform)


def draw(table: ReplayTable, method: str, *, settings: SamplerSettings, minibatches: int,
         seed: int) -> np.ndarray:
    sampler = make_sampler(method, settings)
    rng = np.random.default_rng(seed)
    return np.concatenate([sampler.sample(table.store, BATCH, rng)[0]
                           for _ in range(minibatches)])


def analyse(run_dir: Path, *, every_epochs: int, minibatches: int, moved_m: float,
            seed: int = 0) -> list[dict[str, float]]:
    """One row per checkpoint: epoch, buffer and per-sampler shares."""
    config = load_yaml(RunDir(run_dir).config)
    config = apply_overrides(config, ["run.method=her-cs"])  # keep cluster labels up to date
    per_epoch = config.training.episodes_per_epoch
    table = ReplayBuilder(config).table(rng=np.random.default_rng(seed))
    rows = []
    next_mark = every_epochs * per_epoch
    for message in read_messages(run_dir, [TOPIC_EPISODES, TOPIC_CLUSTER_MODEL]):
        if message.topic == TOPIC_CLUSTER_MODEL:
            table.adopt_cluster_model(msg_to_cluster_model(message.decode_as(pb.ClusterModel)),
                                      None)
            continue
        if message.sequence != table.store.num_inserted:
            raise ValueError(
                f"{run_dir}: the log holds episode {message.sequence} where episode "
                f"{table.store.num_inserted} belongs: its older segments were deleted "
                "(replay.log_max_bytes), and this replays a whole log; keep one with "
                "replay.log_max_bytes=-1")
        table.store_episode(msg_to_episode(message.decode_as(pb.Episode)))
        if table.store.num_inserted < next_mark:
            continue
        next_mark += every_epochs * per_epoch
        everything = np.arange(table.store.size)
        row = {"epoch": table.store.num_inserted / per_epoch, "episodes": table.store.size,
               "model": table.cluster_model.version if table.cluster_model else 0}
        row["buffer_moved"], row["buffer_success"] = episode_mix(table, everything,
                                                                 moved_m=moved_m)
        for method in ("her", "her-cs"):
            slots = draw(table, method, settings=config.sampler_settings,
                         minibatches=minibatches, seed=seed)
            row[f"{method}_moved"], row[f"{method}_success"] = episode_mix(table, slots,
                                                                           moved_m=moved_m)
            row[f"{method}_spread"] = effective_share(slots, table.store.size)
        rows.append(row)
    return rows


def markdown(run_dir: Path, rows: Sequence[dict[str, float]], *, moved_m: float) -> str:
    lines = [f"Sampler mix on `{run_dir.name}` (object moved > {moved_m * 100:g} cm):", "",
             "| epoch | episodes | model | moved: buffer / HER / HER-CS | "
             "succeeded: buffer / HER / HER-CS | spread HER / HER-CS |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['epoch']:.0f} | {r['episodes']:.0f} | v{r['model']:.0f} | "
            f"{r['buffer_moved']:.3f} / {r['her_moved']:.3f} / {r['her-cs_moved']:.3f} | "
            f"{r['buffer_success']:.3f} / {r['her_success']:.3f} / {r['her-cs_success']:.3f} | "
            f"{r['her_spread']:.2f} / {r['her-cs_spread']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", type=Path, help="a run directory (config.yaml + episodes.mcap)")
    p.add_argument("--every-epochs", type=int, default=10)
    p.add_argument("--minibatches", type=int, default=200,
                   help="minibatches of 256 drawn per sampler and checkpoint")
    p.add_argument("--moved", type=float, default=0.01, help="metres (default 0.01)")
    args = p.parse_args(argv)
    if args.every_epochs < 1 or args.minibatches < 1 or args.moved <= 0:
        print("sampler_mix: --every-epochs and --minibatches must be >= 1, --moved > 0",
              file=sys.stderr)
        return 2
    if not RunDir(args.run_dir).config.is_file():
        print(f"sampler_mix: {args.run_dir} has no config.yaml (not a run directory)",
              file=sys.stderr)
        return 2
    try:
        rows = analyse(args.run_dir, every_epochs=args.every_epochs,
                       minibatches=args.minibatches, moved_m=args.moved)
    except ValueError as exc:
        print(f"sampler_mix: {exc}", file=sys.stderr)
        return 2
    print(markdown(args.run_dir, rows, moved_m=args.moved), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
