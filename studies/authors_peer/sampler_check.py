"""Does our HER-CS draw what the authors' sampler draws? Their `her_sampler` is imported from a
checkout (never copied), ours from hercs, on their peer runs' cluster sizes and a peer snapshot.

    python -m studies.authors_peer.sampler_check --checkout PATH [--snapshot RUN/peer_state]

→ docs/results/authors_sampler.{md,json}; the question is in docs/results/README.md."""

from __future__ import annotations

import argparse
import csv
import importlib
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hercs.rl.cluster_model import assign_clusters
from hercs.rl.samplers.cluster_balanced import ClusterBalancedSampler, plan_shares
from hercs.rl.samplers.sampling_index import SamplingIndex
from hercs.rl.samplers.share_rules import SHARE_RULES
from studies.authors_peer.peer_run import checkout_commit
from studies.study_output import (
    FINDINGS_HEADING,
    REPO,
    add_out_option,
    git_commit,
    kept_findings,
    report_folder,
    write_report,
)

NAME = "authors_sampler"
BATCH = 256
SMALL_CLUSTER_REPEAT = 4  # their her.py: a cluster under share/4 members gets 4 draws each
MOVED_M, LIFTED_M, SUCCESS_M = 0.005, 0.03, 0.05


def episode_kinds(ag: np.ndarray, goal: np.ndarray) -> dict[str, np.ndarray]:
    """(N, T+1, 3) achieved goals and (N, 3) goals → per episode: moved, lifted, success."""
    final = ag[:, -1]
    return {"moved": np.linalg.norm(ag - ag[:, :1], axis=-1).max(axis=1) > MOVED_M,
            "lifted": final[:, 2] > ag[:, 0, 2] + LIFTED_M,
            "success": np.linalg.norm(final - goal, axis=-1) < SUCCESS_M}


def their_sampler(checkout: Path) -> Any:
    """Their `her_sampler('future', 4)` from the checkout (her_modules/her.py)."""
    sys.path.insert(0, str(checkout))
    return importlib.import_module("her_modules.her").her_sampler("future", 4, None)


def labels_of(sizes: Sequence[int]) -> np.ndarray:
    """A buffer whose episodes carry these cluster sizes, label by label."""
    return np.repeat(np.arange(len(sizes)), sizes).astype(np.int64)


def their_clusters(labels: np.ndarray) -> list[list[int]]:
    """The members of each label up to the highest present, as their replay buffer hands them
    to `clustering_her_random` (an empty label is an empty list)."""
    return [np.flatnonzero(labels == c).tolist() for c in range(int(labels.max()) + 1)]


def their_draws(sampler: Any, labels: np.ndarray, k: int, batches: int) -> np.ndarray:
    """Mean draws per cluster label (0..k-1) in one batch of their sampler, over `batches`."""
    clustered = their_clusters(labels)
    counts = np.zeros(k)
    for _ in range(batches):
        counts += np.bincount(labels[sampler.clustering_her_random(len(labels), BATCH,
                                                                   clustered)], minlength=k)
    return counts / batches


def our_draws(labels: np.ndarray, k: int, share_rule: str) -> np.ndarray:
    """Expected draws per cluster in one batch of ours: its members' draws, plus its part
    of the whole-buffer fill."""
    index = SamplingIndex(len(labels))
    index.rebuild(np.zeros(len(labels)), labels)
    plan = plan_shares(index, k=k, repeat=SMALL_CLUSTER_REPEAT, batch_size=BATCH,
                       share_rule=share_rule)
    assert plan is not None
    return plan.member_draws + plan.fill * plan.sizes / len(labels)


def per_epoch_plans(metrics: Path, sampler: Any, batches: int) -> list[dict[str, Any]]:
    """For each epoch of a peer run with a cluster model: the most draws any cluster gets
    more or fewer from our plan (each share rule) than from their sampler."""
    rows = []
    with metrics.open() as f:
        for row in csv.DictReader(f):
            if not row.get("cluster_sizes") or row.get("cluster_fitted") != "1":
                continue
            sizes = [int(x) for x in row["cluster_sizes"].split(";")]
            labels = labels_of(sizes)
            theirs = their_draws(sampler, labels, len(sizes), batches)
            entry: dict[str, Any] = {"epoch": int(row["epoch"]), "sizes": sizes,
                                     "top_empty": sizes[-1] == 0}
            for rule in SHARE_RULES:
                entry[rule] = float(np.abs(our_draws(labels, len(sizes), rule) - theirs).max())
            rows.append(entry)
    return rows


class SnapshotBuffer:
    """A peer snapshot's buffer as our samplers read a store (SampleSource)."""

    def __init__(self, cluster: np.ndarray) -> None:
        self.cluster = cluster
        self.size = len(cluster)
        self.energy = np.zeros(self.size)
        self.sampling_index = SamplingIndex(self.size)
        self.sampling_index.rebuild(self.energy, cluster.astype(np.int64))


def snapshot_mix(snapshot: Path, sampler: Any, batches: int, seed: int) -> dict[str, Any]:
    """On a peer snapshot's buffer, labelled by its own centres: the share of moved, lifted
    and successful episodes in the buffer, in their batches and in ours (each share rule)."""
    with np.load(snapshot / "arrays.npz", allow_pickle=False) as z:
        ag, g, centres = z["buffer.ag"], z["buffer.g"][:, -1, :], z["cluster_centers"]
    kinds = episode_kinds(ag, g)
    labels = assign_clusters(ag[:, -1, :], centres).astype(np.int64)
    np.random.seed(seed)
    clustered = their_clusters(labels)
    drawn = {"buffer (HER's uniform draw)": np.arange(len(labels)),
             "their sampler": np.concatenate([sampler.clustering_her_random(
                 len(labels), BATCH, clustered) for _ in range(batches)])}
    rng = np.random.default_rng(seed)
    store = SnapshotBuffer(labels.astype(np.int32))
    for rule in SHARE_RULES:
        ours = ClusterBalancedSampler(len(centres), share_rule=rule)
        drawn[f"ours, share rule {rule}"] = np.concatenate(
            [ours.sample(store, BATCH, rng)[0] for _ in range(batches)])
    return {"episodes": len(labels), "sizes": np.bincount(labels, minlength=len(centres)).tolist(),
            "shares": {who: {kind: float(mask[idx].mean()) for kind, mask in kinds.items()}
                       for who, idx in drawn.items()}}


def render(summary: dict[str, Any], findings: str) -> str:
    lines = [f"# {NAME}: our HER-CS draw against the authors' sampler", "",
             f"`python -m studies.authors_peer.sampler_check` at {summary['commit']}, their "
             f"code at their {summary['their_commit']}; {summary['batches']} batches of "
             f"{BATCH} per case.",
             "", "## Draws per cluster on their runs' cluster sizes", "",
             "Per peer run, over its epochs with a cluster model: the largest difference, in "
             "draws of one batch, between one cluster's draws from our plan (expected) and from "
             "their sampler (the mean over the batches, whose sd is at most about "
             f"{summary['noise_draws']:.1f} draws, so that the largest of 8 clusters × the "
             "epochs runs to 3–4 sd from noise alone).", "",
             "| run | epochs | top cluster empty | " + " | ".join(
                 f"max diff, {r}" for r in SHARE_RULES) + " |",
             "|---|---|---|" + "---|" * len(SHARE_RULES)]
    for run, rows in summary["plans"].items():
        empty = sum(r["top_empty"] for r in rows)
        lines.append(f"| {run} | {len(rows)} | {empty} | " + " | ".join(
            f"{max(r[rule] for r in rows):.1f}" for rule in SHARE_RULES) + " |")
    snap = summary.get("snapshot")
    if snap:
        lines += ["", f"## The episodes drawn, on a peer snapshot's buffer ({snap['path']})", "",
                  f"{snap['episodes']} episodes, cluster sizes {snap['sizes']}; moved: the "
                  f"object went ≥ {MOVED_M * 1000:.0f} mm from its start, lifted: ended ≥ "
                  f"{LIFTED_M * 100:.0f} cm above it, success: ended within "
                  f"{SUCCESS_M * 100:.0f} cm of the goal.", "",
                  "| drawn by | moved | lifted | success |", "|---|---|---|---|"]
        for who, shares in snap["shares"].items():
            lines.append(f"| {who} | {shares['moved']:.3f} | {shares['lifted']:.3f} | "
                         f"{shares['success']:.3f} |")
    lines += ["", FINDINGS_HEADING, "", findings or "(not written yet)", ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.authors_peer.sampler_check",
                                description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--checkout", type=Path, required=True,
                   help="a checkout of the authors' repository (outside this one)")
    p.add_argument("--runs", type=Path, nargs="*", default=None,
                   help="peer run folders with metrics.csv (default: the committed ones)")
    p.add_argument("--snapshot", type=Path, help="a peer run's peer_state folder")
    p.add_argument("--batches", type=int, default=200)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--quick", action="store_true", help="20 batches, one run, 10 epochs")
    add_out_option(p, NAME)
    args = p.parse_args(argv)
    if not (args.checkout / "her_modules" / "her.py").is_file():
        p.error(f"--checkout {args.checkout}: no her_modules/her.py (not their repository)")
    if args.snapshot and not (args.snapshot / "arrays.npz").is_file():
        p.error(f"--snapshot {args.snapshot}: no arrays.npz (not a peer_state folder)")
    batches = 20 if args.quick else args.batches
    if batches < 1:
        p.error(f"--batches {batches}: must be >= 1")
    runs = args.runs or sorted((REPO / "docs/results/runs").glob("*-authors-code-s*"))
    sampler = their_sampler(args.checkout.resolve())
    np.random.seed(args.seed)
    plans = {}
    for run in runs[:1] if args.quick else runs:
        rows = per_epoch_plans(run / "metrics.csv", sampler, batches)
        plans[run.name] = rows[-10:] if args.quick else rows
    summary: dict[str, Any] = {"commit": git_commit(), "batches": batches, "plans": plans,
                               "their_commit": checkout_commit(args.checkout),
                               # the sd of a mean of `batches` draws of at most ~share(≈36)
                               "noise_draws": float(np.sqrt(36 / batches))}
    if args.snapshot:
        summary["snapshot"] = {"path": args.snapshot.parent.name,
                               **snapshot_mix(args.snapshot, sampler, batches, args.seed)}
    out = report_folder(args.out, args.quick, REPO)
    findings = kept_findings(out / f"{NAME}.md") if out else ""
    text = render(summary, findings)
    print(text)
    write_report(out, NAME, summary, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
