"""In-process cost of one minibatch: the episode draw of each sampler and HER's relabelling.

    python -m bench.perf.sampling [--quick] [--out docs/results/sampling]

Ours against the same draw rebuilt from the store on every call, at 1e6 transitions. Writes
OUT.json and OUT.md; method and results: docs/results/sampling.md, docs/PERFORMANCE.md §5."""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from bench.common import REPO, git_commit
from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides
from hercs.replay_service.her import relabel
from hercs.replay_service.store import EpisodeStore
from hercs.rl.methods import make_sampler
from hercs.rl.samplers.base import make_info

METHODS = ("her", "her-cs", "her-ebp", "her-ebp-cs")
BATCH = 256
K = 8
TARGET_MS = 0.3


def fill_store(episodes: int, seed: int = 0) -> tuple[EpisodeStore, HercsConfig]:
    config = apply_overrides(HercsConfig(), ["task.name=push"])
    spec = config.task.spec
    store = EpisodeStore(capacity_episodes=episodes, spec=spec)
    rng = np.random.default_rng(seed)
    pool = [random_episode(spec, rng, seq=i) for i in range(min(episodes, 200))]
    for i in range(episodes):
        store.insert(pool[i % len(pool)], energy=float(rng.exponential(0.05)))
    store.set_clusters(rng.integers(0, K, episodes).astype(np.int32))
    return store, config


def reference_draw(method: str, store: EpisodeStore, *, epsilon: float, repeat: int,
                   rng: np.random.Generator) -> np.ndarray:
    """The episode draw as the samplers made it before `SamplingIndex` (per-call O(N)),
    with the per-cluster counts every sampler reports (`make_info`)."""
    slots = _reference_slots(method, store, epsilon=epsilon, repeat=repeat, rng=rng)
    make_info(store.cluster, slots, num_clusters=K)
    return slots


def _reference_slots(method: str, store: EpisodeStore, *, epsilon: float, repeat: int,
                     rng: np.random.Generator) -> np.ndarray:
    if method == "her":
        return rng.integers(0, store.size, BATCH)
    labels = store.cluster
    if method == "her-ebp":
        cum = np.concatenate([[0.0], np.cumsum(store.energy + epsilon)])
        return np.searchsorted(cum, rng.uniform(size=BATCH) * cum[-1], side="right") - 1
    shifted = labels + 1
    counts = np.bincount(shifted, minlength=K + 1)
    order = np.argsort(shifted.astype(np.int8), kind="stable")
    starts, sizes = np.cumsum(counts)[:-1], counts[1:]
    share = BATCH // K
    draws = np.where(sizes < share // repeat, repeat * sizes, share)
    of = np.repeat(np.arange(K), draws)
    fill = BATCH - int(draws.sum())
    if method == "her-cs":
        members = order[starts[of] + rng.integers(0, sizes[of])]
        return np.concatenate([members, rng.integers(0, store.size, fill)])
    cum = np.concatenate([[0.0], np.cumsum((store.energy + epsilon)[order])])
    lo, hi = starts[of], starts[of] + sizes[of]
    target = cum[lo] + rng.uniform(size=lo.size) * (cum[hi] - cum[lo])
    members = np.clip(np.searchsorted(cum, target, side="right") - 1, lo, hi - 1)
    fills = np.searchsorted(cum, rng.uniform(size=fill) * cum[-1], side="right") - 1
    return order[np.concatenate([members, fills])]


def measure(store: EpisodeStore, config: HercsConfig, *, rounds: int, per_round: int
            ) -> dict[str, dict[str, list[float]]]:
    """ms per minibatch, per method and part, interleaved round by round."""
    times: dict[str, dict[str, list[float]]] = {
        m: {"draw": [], "relabel": [], "draw+relabel": [], "reference draw": [],
            "with inserts": []}
        for m in METHODS}
    episode = random_episode(config.task.spec, np.random.default_rng(2))
    samplers = {m: make_sampler(m, apply_overrides(config, [f"run.method={m}"]).sampler_settings)
                for m in METHODS}
    rng = np.random.default_rng(1)
    spec, future_p = config.task.spec, config.her.future_p
    eps, repeat = config.energy_epsilon, config.cluster.small_cluster_repeat
    for _ in range(rounds):
        for method in METHODS:
            sampler, part = samplers[method], times[method]
            for _ in range(per_round):
                t0 = time.perf_counter()
                slots, _ = sampler.sample(store, BATCH, rng)
                t1 = time.perf_counter()
                relabel(store, slots, future_p=future_p, reward_fn=spec.compute_reward,
                        rng=rng)
                t2 = time.perf_counter()
                relabel(store, sampler.sample(store, BATCH, rng)[0], future_p=future_p,
                        reward_fn=spec.compute_reward, rng=rng)
                t3 = time.perf_counter()
                reference_draw(method, store, epsilon=eps, repeat=repeat, rng=rng)
                t4 = time.perf_counter()
                for name, ms in (("draw", t1 - t0), ("relabel", t2 - t1),
                                 ("draw+relabel", t3 - t2), ("reference draw", t4 - t3)):
                    part[name].append(ms * 1e3)
            # the paper's schedule: one episode inserted (evicting the oldest) per 10
            # minibatches, so the index's cached sums are recomputed once per 10 draws
            for _ in range(per_round // 10):
                store.insert(episode, energy=float(rng.exponential(0.05)),
                             cluster=int(rng.integers(0, K)))
                t0 = time.perf_counter()
                for _ in range(10):
                    relabel(store, sampler.sample(store, BATCH, rng)[0], future_p=future_p,
                            reward_fn=spec.compute_reward, rng=rng)
                part["with inserts"].append((time.perf_counter() - t0) * 1e3 / 10)
    return times


def summarise(times: dict[str, dict[str, list[float]]]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for method, parts in times.items():
        row: dict[str, float] = {}
        for part, values in parts.items():
            row[f"{part} p50"] = float(np.percentile(values, 50))
            row[f"{part} p99"] = float(np.percentile(values, 99))
        row["draw ratio p50"] = row["draw p50"] / row["reference draw p50"]
        out[method] = row
    return out


def report(summary: dict[str, dict[str, float]], *, episodes: int, command: str) -> str:
    lines = [
        "# In-process sampling cost per minibatch",
        "",
        f"`{command}` — {episodes:,} FetchPush episodes ({episodes * 50:,} transitions), "
        f"B={BATCH}, k={K}; git {git_commit()}, {platform.processor() or platform.machine()}.",
        "",
        "| method | draw p50 | draw p99 | reference draw p50 | draw ratio | relabel p50 | "
        f"draw+relabel p50 | draw+relabel p99 | with inserts, mean of 10 (p50) | "
        f"target ≤ {TARGET_MS} ms |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for method, r in summary.items():
        meets = "meets" if r["draw+relabel p50"] <= TARGET_MS else "misses"
        lines.append(
            f"| {method} | {r['draw p50']:.3f} ms | {r['draw p99']:.3f} ms | "
            f"{r['reference draw p50']:.3f} ms | {r['draw ratio p50']:.2f} | "
            f"{r['relabel p50']:.3f} ms | {r['draw+relabel p50']:.3f} ms | "
            f"{r['draw+relabel p99']:.3f} ms | {r['with inserts p50']:.3f} ms | "
            f"{meets} (p50) |")
    lines += [
        "",
        "draw = `sampler.sample` on the store's `SamplingIndex`; reference draw = the same "
        "law rebuilt from the store per call (as before the index); relabel = HER future "
        "relabelling and the gather of one minibatch; with inserts = draw+relabel averaged "
        "over the 10 minibatches after an insert (the paper's 10 updates per episode), "
        "which pays the index's recomputation of its cached energy sums once. Rounds "
        "alternate the methods and parts, so a busy machine slows all of them alike; the "
        "ratio is the figure to read.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="500 episodes, few rounds")
    parser.add_argument("--out", default=str(REPO / "docs/results/sampling"),
                        help="write OUT.json and OUT.md (default docs/results/sampling)")
    args = parser.parse_args(argv)
    episodes = 500 if args.quick else 20_000
    rounds, per_round = (3, 20) if args.quick else (20, 50)
    store, config = fill_store(episodes)
    measure(store, config, rounds=1, per_round=5)  # warm-up
    summary = summarise(measure(store, config, rounds=rounds, per_round=per_round))
    command = "python -m bench.perf.sampling" + (" --quick" if args.quick else "")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(
        {"episodes": episodes, "batch": BATCH, "k": K, "git": git_commit(),
         "target_ms": TARGET_MS, "results": summary}, indent=2) + "\n")
    text = report(summary, episodes=episodes, command=command)
    out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
