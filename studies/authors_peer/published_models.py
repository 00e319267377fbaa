"""The trained policies the authors publish, tested on our simulators: does a policy trained
on their simulator succeed on ours as often as it did on theirs?

    python -m studies.authors_peer.published_models --checkout PATH   # ~22 min beside two runs

Their repository ships one actor per seed for PickAndPlace (`saved_models/FetchPickAndPlace-
v1/model<seed>.pt`: the input normaliser's means and deviations and the actor's weights,
saved after every epoch by their `ddpg_agent.py`, so the last one, epoch 200; which of their
four methods made them is not stated). Each is run with their test protocol (`_eval_agent`:
the deterministic actor on normalised inputs, 50 steps, success read at the last step) on
our v1 (gymnasium-robotics' mujoco-py FetchPickAndPlace-v1) and v4, the same reset seeds
for every model. Beside it, what their curves say each seed reached at its last epochs on
their own simulator. Writes docs/results/authors_models.{json,md} (or --out).

The files are pickles: they are read with `torch.load(weights_only=True)` and only the numpy
types a normaliser needs allowed, so a file that would run code is refused, not run."""

from __future__ import annotations

import argparse
import csv
import importlib.util
import math
import sys
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from studies.authors_peer.peer_run import checkout_commit, make_gymnasium_env
from studies.study_output import (
    FINDINGS_HEADING,
    REPO,
    add_out_option,
    git_commit,
    kept_findings,
    report_folder,
    write_report,
)

MODELS = Path("saved_models") / "FetchPickAndPlace-v1"
SEEDS = (121, 123, 125, 127, 133)
VERSIONS = ("v1", "v4")
EVAL_SEED = 990_000
"""Reset seeds of the test episodes (EVAL_SEED + i): the same goals for every model and
simulator."""
CLIP_RANGE = 5.0
"""Their normaliser's clip (`--clip-range`, default 5): inputs are clipped to ±5 std."""
PUBLISHED = REPO / "docs" / "reference" / "authors_success_rates.csv"
LAST_EPOCHS = 10
"""Their curves' last epochs averaged for 'on their simulator' (10 test episodes each)."""


class PublishedModel:
    """One of their saved actors with its input normaliser, ready to act."""

    def __init__(self, path: Path, checkout: Path) -> None:
        import torch

        o_mean, o_std, g_mean, g_std, weights = load_pickled_model(path)
        models = their_models_module(checkout)
        obs, goal = len(o_mean), len(g_mean)
        action = int(weights["action_out.weight"].shape[0])
        self.actor = models.actor({"obs": obs, "goal": goal, "action": action,
                                   "action_max": 1.0})
        self.actor.load_state_dict(weights)
        self.actor.eval()
        self.norm = (np.asarray(o_mean), np.asarray(o_std), np.asarray(g_mean),
                     np.asarray(g_std))
        self._torch = torch

    def act(self, obs: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Their `_preproc_inputs` then the actor, as in their `_eval_agent`."""
        o_mean, o_std, g_mean, g_std = self.norm
        inputs = np.concatenate([np.clip((obs - o_mean) / o_std, -CLIP_RANGE, CLIP_RANGE),
                                 np.clip((goal - g_mean) / g_std, -CLIP_RANGE, CLIP_RANGE)])
        with self._torch.no_grad():
            x = self._torch.tensor(inputs, dtype=self._torch.float32).unsqueeze(0)
            return self.actor(x).numpy().squeeze()


def their_models_module(checkout: Path) -> ModuleType:
    """Their `rl_modules/models.py` (the `actor` they build), loaded from the file under a
    name of its own: neither sys.path nor an `rl_modules` another study imported is touched."""
    path = checkout / "rl_modules" / "models.py"
    spec = importlib.util.spec_from_file_location("_authors_published_models", path)
    if spec is None or spec.loader is None:
        raise FileNotFoundError(f"{path}: their models module is not there")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_pickled_model(path: Path) -> list[Any]:
    """[o_mean, o_std, g_mean, g_std, actor state dict] from one of their files, on the CPU
    (they saved CUDA tensors). Only tensors and the numpy arrays and dtypes of the normaliser
    are allowed to be built: any other global in the pickle raises UnpicklingError before
    anything of it runs."""
    import torch
    from numpy._core.multiarray import _reconstruct

    # numpy < 2 (theirs) and numpy 2 name the array builder differently
    allowed = [(_reconstruct, "numpy.core.multiarray._reconstruct"), _reconstruct, np.ndarray,
               (np.dtype, "numpy.dtype"),
               *(type(np.dtype(t)) for t in (np.float32, np.float64))]
    with torch.serialization.safe_globals(allowed):
        loaded = torch.load(path, weights_only=True, map_location="cpu")
    if not (isinstance(loaded, list) and len(loaded) == 5 and isinstance(loaded[4], dict)):
        raise ValueError(f"{path}: not their [o_mean, o_std, g_mean, g_std, actor weights]")
    return loaded


def success_rate(model: PublishedModel, version: str, episodes: int) -> float:
    """Share of `episodes` test episodes on `version` successful at their last step."""
    env = make_gymnasium_env(f"FetchPickAndPlace-{version}")
    steps = env.spec.max_episode_steps if env.spec else 50
    wins = 0
    try:
        for i in range(episodes):
            obs, _ = env.reset(seed=EVAL_SEED + i)
            info: dict[str, Any] = {}
            for _ in range(steps):
                obs, _, _, _, info = env.step(model.act(obs["observation"],
                                                        obs["desired_goal"]))
            wins += int(info["is_success"])
    finally:
        env.close()
    return wins / episodes


def wilson(k: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson interval of a binomial share k/n."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def published_last_epochs(path: Path = PUBLISHED) -> dict[str, dict[int, float]]:
    """Per method and seed, their PickAndPlace curve's mean over its last LAST_EPOCHS."""
    curves: dict[str, dict[int, list[tuple[int, float]]]] = {}
    with path.open() as f:
        for row in csv.DictReader(f):
            if row["task"] == "FetchPickAndPlace":
                curves.setdefault(row["method"], {}).setdefault(int(row["seed"]), []).append(
                    (int(row["epoch"]), float(row["success_rate"])))
    return {m: {s: float(np.mean([v for _, v in sorted(c)[-LAST_EPOCHS:]]))
                for s, c in by_seed.items()} for m, by_seed in curves.items()}


def report(summary: dict[str, Any]) -> str:
    n = summary["episodes"]
    methods = list(summary["published"])
    lines = ["# The authors' published PickAndPlace policies on our simulators", "",
             f"`python -m studies.authors_peer.published_models"
             f"{' --quick' if summary['quick'] else ''}` — "
             f"{summary['date']}, commit {summary['commit']}, their checkout "
             f"{summary['checkout_commit']}. Each of their five saved actors "
             f"(`{MODELS}/model<seed>.pt`, their last epoch, 200) run on {n} test episodes "
             "per simulator by their test protocol, the same reset seeds for all; 95 % "
             "Wilson intervals. 'Their simulator': their curves' mean over the last "
             f"{LAST_EPOCHS} epochs (191–200, 10 test episodes each) for that seed, per "
             "method, since which method saved the files is not stated.", "",
             "| seed | our v1 | our v4 | "
             + " | ".join(f"their simulator, {m}" for m in methods) + " |",
             "|---|---|---|" + "---|" * len(methods)]
    for seed in summary["seeds"]:
        cells = []
        for version in summary["versions"]:
            r = summary["results"][str(seed)][version]
            cells.append(f"{r['success']:.2f} [{r['low']:.2f}, {r['high']:.2f}]")
        theirs = [f"{summary['published'][m][str(seed)]:.2f}" for m in methods]
        lines.append(f"| {seed} | " + " | ".join(cells + theirs) + " |")
    pooled = summary["pooled"]
    lines += ["", "All five pooled: " + "; ".join(
        f"our {v} {pooled[v]['success']:.3f} [{pooled[v]['low']:.3f}, {pooled[v]['high']:.3f}]"
        for v in summary["versions"]) + f" ({len(summary['seeds']) * n} episodes each)."]
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.authors_peer.published_models",
                                description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--checkout", type=Path, required=True,
                   help="a checkout of the authors' repository (outside this one)")
    p.add_argument("--episodes", type=int, default=200, help="test episodes per model and "
                   "simulator (default 200)")
    p.add_argument("--versions", nargs="+", default=list(VERSIONS), choices=VERSIONS)
    p.add_argument("--quick", action="store_true", help="CI: 2 episodes, seed 121 only")
    add_out_option(p, "authors_models")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes {args.episodes}: must be >= 1")
    folder = args.checkout / MODELS
    seeds = SEEDS[:1] if args.quick else SEEDS
    missing = [s for s in seeds if not (folder / f"model{s}.pt").is_file()]
    if missing:
        p.error(f"--checkout {args.checkout}: no {MODELS}/model<seed>.pt for seeds {missing}")
    episodes = 2 if args.quick else args.episodes
    start = time.monotonic()
    results: dict[str, dict[str, dict[str, float]]] = {}
    wins = dict.fromkeys(args.versions, 0.0)
    for seed in seeds:
        model = PublishedModel(folder / f"model{seed}.pt", args.checkout)
        results[str(seed)] = {}
        for version in args.versions:
            rate = success_rate(model, version, episodes)
            low, high = wilson(rate * episodes, episodes)
            results[str(seed)][version] = {"success": rate, "low": low, "high": high}
            wins[version] += rate * episodes
            print(f"model{seed} on {version}: {rate:.3f} [{low:.3f}, {high:.3f}]", flush=True)
    total = episodes * len(seeds)
    pooled = {v: dict(zip(("success", "low", "high"),
                          (wins[v] / total, *wilson(wins[v], total)), strict=True))
              for v in args.versions}
    published = {m: {str(s): v for s, v in by_seed.items()}
                 for m, by_seed in published_last_epochs().items()}
    summary = {"date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
               "commit": git_commit(), "checkout_commit": checkout_commit(args.checkout),
               "quick": args.quick, "episodes": episodes, "seeds": list(seeds),
               "versions": args.versions, "eval_seed": EVAL_SEED, "results": results,
               "pooled": pooled, "published": published,
               "seconds": round(time.monotonic() - start, 1)}
    out = report_folder(args.out, args.quick, REPO)
    text = report(summary)
    # the reading is written by hand from the table; a rerun keeps it, to be re-read
    findings = kept_findings(out / "authors_models.md") if out is not None else ""
    if findings:
        text += f"\n{FINDINGS_HEADING}\n\n{findings}"
    print(text)
    write_report(out, "authors_models", summary, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
