"""What the training episodes did, epoch by epoch: the share that moved, lifted or reached the
object's goal, from our runs' episode logs and from a peer run's snapshot (whose buffer holds
every episode in order until it fills at epoch 100).

    python -m studies.authors_peer.acted_episodes RUN_OR_PEER_STATE... [--block 10]
→ docs/results/acted_episodes.{md,json}; the question is in docs/results/README.md."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hercs.run.runlog.reader import read_episode_messages
from hercs.wire.codec import msg_to_episode
from studies.authors_peer.sampler_check import (
    LIFTED_M,
    MOVED_M,
    SUCCESS_M,
    episode_kinds,
)
from studies.study_output import (
    FINDINGS_HEADING,
    REPO,
    add_out_option,
    git_commit,
    kept_findings,
    report_folder,
    write_report,
)

NAME = "acted_episodes"
KINDS = ("moved", "lifted", "success")


def is_peer_state(path: Path) -> bool:
    """A peer run's snapshot folder (its buffer in arrays.npz), not a run folder."""
    return (path / "arrays.npz").is_file()


def run_folder(path: Path) -> Path:
    """The run folder holding config.yaml: a peer snapshot's parent, else the path itself."""
    return path.parent if is_peer_state(path) else path


def load_source(path: Path) -> tuple[str, int, np.ndarray, np.ndarray]:
    """(name, episodes an epoch, ag, goal) of the episodes of the run's epochs in acting order
    (episode id // episodes an epoch is the epoch of the lockstep schedule; an asynchronous
    run's actors act a few past the last epoch, left out): a peer_state folder's buffer, or
    a run directory's episode log; the epoch's size and count from the run's config.yaml."""
    peer = is_peer_state(path)
    run = run_folder(path)
    config = yaml.safe_load((run / "config.yaml").read_text())["training"]
    per_epoch = int(config["cycles_per_epoch"]) * int(config["episodes_per_cycle"])
    last = per_epoch * int(config["epochs"])
    if peer:
        with np.load(path / "arrays.npz", allow_pickle=False) as z:
            return run.name, per_epoch, z["buffer.ag"][:last], z["buffer.g"][:last, -1]
    ags, goals = [], []
    for episode_id, message in read_episode_messages(path):
        if episode_id < last:
            episode = msg_to_episode(message)
            ags.append(episode.ag)
            goals.append(episode.g[-1])
    return run.name, per_epoch, np.asarray(ags), np.asarray(goals)


def blocks(kinds: dict[str, np.ndarray], episodes: int) -> list[dict[str, float]]:
    """Each kind's share of the episodes acted in each whole block of `episodes`."""
    n = len(next(iter(kinds.values()))) // episodes
    return [{kind: float(mask[i * episodes:(i + 1) * episodes].mean())
             for kind, mask in kinds.items()} for i in range(n)]


def render(summary: dict[str, Any], findings: str) -> str:
    block = summary["block_epochs"]
    width = max(len(rows) for rows in summary["runs"].values())
    head = " | ".join(f"{i * block}–{(i + 1) * block - 1}" for i in range(width))
    lines = [f"# {NAME}: what the training episodes did", "",
             f"`python -m studies.authors_peer.acted_episodes` at {summary['commit']}. The "
             f"share of the training episodes acted in each block of {block} epochs (epochs "
             "from 0; exploration noise included) "
             f"that moved the object ≥ {MOVED_M * 1000:.0f} mm, ended it ≥ "
             f"{LIFTED_M * 100:.0f} cm above its start (lifted), or ended within "
             f"{SUCCESS_M * 100:.0f} cm of the goal.", ""]
    for kind in KINDS:
        lines += [f"## {kind}", "", f"| run | {head} |", "|---|" + "---|" * width]
        for run, rows in summary["runs"].items():
            cells = [f"{r[kind]:.3f}" for r in rows] + ["–"] * (width - len(rows))
            lines.append(f"| {run} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += [FINDINGS_HEADING, "", findings or "(not written yet)", ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.authors_peer.acted_episodes",
                                description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("sources", type=Path, nargs="+",
                   help="run directories with an episode log, or peer runs' peer_state folders")
    p.add_argument("--block", type=int, default=10, help="epochs a column (default 10)")
    p.add_argument("--quick", action="store_true", help="print only (no report written)")
    add_out_option(p, NAME)
    args = p.parse_args(argv)
    if args.block < 1:
        p.error(f"--block {args.block}: must be >= 1")
    for source in args.sources:
        run = run_folder(source)
        if not (run / "config.yaml").is_file():
            p.error(f"{source}: neither a run folder nor a peer run's peer_state (no "
                    f"config.yaml in {run})")
    runs = {}
    for source in args.sources:
        name, per_epoch, ag, goal = load_source(source)
        if len(ag) < per_epoch * args.block:
            print(f"{source}: {len(ag)} episodes, not one block of {args.block} epochs "
                  f"({per_epoch} episodes each); left out", file=sys.stderr)
            continue
        runs[name] = blocks(episode_kinds(ag, goal), per_epoch * args.block)
    if not runs:
        print("acted_episodes: no source holds a whole block; nothing to report", file=sys.stderr)
        return 2
    summary = {"commit": git_commit(), "block_epochs": args.block, "runs": runs}
    out = report_folder(args.out, args.quick, REPO)
    text = render(summary, kept_findings(out / f"{NAME}.md") if out else "")
    print(text)
    write_report(out, NAME, summary, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
