"""The trained policies the authors publish, tested on our simulators: does a policy trained
on their simulator succeed on ours as often as it did on theirs?

    python -m studies.authors_peer.published_models --checkout PATH   # ~22 min beside two runs

Their repository ships one actor per seed for PickAndPlace (`saved_models/FetchPickAndPlace-
v1/model<seed>.pt`: the input normaliser's means and deviations and the actor's weights,
overwritten after every epoch by their `ddpg_agent.py`, so presumably their runs' last,
epoch 200; which of their four methods made them is not stated). Each is run with their
test protocol (`_eval_agent`: the deterministic actor on normalised inputs, 50 steps,
success read at the last step) on our v1 (gymnasium-robotics' mujoco-py
FetchPickAndPlace-v1) and v4, the same reset seeds for every model. Beside it, what their
curves say each seed reached over its last epochs on their own simulator. Writes
docs/results/authors_models.{json,md} (or --out).

The files are pickles: they are read with `torch.load(weights_only=True)` and only the numpy
types a normaliser needs allowed, so a file that would run code is refused, not run. Nothing
of their checkout is imported: the actor (three ReLU layers, tanh) is built here and their
weights loaded into it strictly.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from hercs.apps.plots.curves import load_reference
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
ACTION_MAX = 1.0
"""Fetch's action bound (their `env_params['action_max']`)."""
CLIP_RANGE = 5.0
"""Their normaliser's clip (`--clip-range`, default 5): inputs are clipped to ±5 std."""
PUBLISHED = REPO / "docs" / "reference" / "authors_success_rates.csv"
LAST_EPOCHS = 10
"""Their curves' last epochs averaged for 'on their simulator' (20 test episodes each, their
`--n-test-rollouts`)."""


ACTOR_LAYERS = ("fc1", "fc2", "fc3", "action_out")
"""Their actor (`rl_modules/models.py`): three 256-unit ReLU layers, then tanh × max_action."""


def their_actor(weights: dict[str, Any]) -> Any:
    """Their actor's architecture, built here from the layer shapes in `weights` (nothing of
    their checkout is imported or run), the weights loaded strictly: a file whose layers are
    not theirs raises."""
    import torch
    from torch import nn

    names = {key.rsplit(".", 1)[0] for key in weights}
    if names != set(ACTOR_LAYERS):
        raise ValueError(f"not their actor's layers {ACTOR_LAYERS}: {sorted(names)}")

    class Actor(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            for name in ACTOR_LAYERS:
                out_size, in_size = weights[f"{name}.weight"].shape
                setattr(self, name, nn.Linear(int(in_size), int(out_size)))

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            for name in ACTOR_LAYERS[:-1]:
                x = torch.relu(getattr(self, name)(x))
            return ACTION_MAX * torch.tanh(self.action_out(x))

    actor = Actor()
    actor.load_state_dict(weights)  # strict: every weight of theirs, nothing else
    return actor.eval()


class PublishedModel:
    """One of their saved actors with its input normaliser, ready to act."""

    def __init__(self, path: Path) -> None:
        import torch

        o_mean, o_std, g_mean, g_std, weights = load_pickled_model(path)
        self.actor = their_actor(weights)
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


def published_last_epochs(path: Path = PUBLISHED) -> tuple[dict[str, dict[int, float]], int]:
    """Per method and seed, their PickAndPlace curve's mean over its last LAST_EPOCHS; and
    the curves' last epoch."""
    curves = [c for c in load_reference(path) if c.task == "FetchPickAndPlace"]
    means: dict[str, dict[int, float]] = {}
    for c in curves:  # load_reference gives each curve's epochs in order
        means.setdefault(c.method, {})[c.seed] = float(np.mean(c.success[-LAST_EPOCHS:]))
    return means, max(int(c.epochs[-1]) for c in curves)


def report(summary: dict[str, Any]) -> str:
    n, last = summary["episodes"], summary["published_last_epoch"]
    methods = list(summary["published"])
    lines = ["# The authors' published PickAndPlace policies on our simulators", "",
             f"`python -m studies.authors_peer.published_models"
             f"{' --quick' if summary['quick'] else ''}` — "
             f"{summary['date']}, commit {summary['commit']}, their checkout "
             f"{summary['checkout_commit']}. Each of their five saved actors "
             f"(`{MODELS}/model<seed>.pt`, presumably their last epoch, {last}) run on {n} "
             "test episodes per simulator by their test protocol, the same reset seeds for "
             "all; 95 % Wilson intervals. 'Their simulator': their curves' mean over the last "
             f"{LAST_EPOCHS} epochs ({last - LAST_EPOCHS + 1}–{last}, 20 test episodes each) "
             "for that seed, per method, since which method saved the files is not stated.",
             "",
             "| seed | our v1 | our v4 | "
             + " | ".join(f"their simulator, {m}" for m in methods) + " |",
             "|---|---|---|" + "---|" * len(methods)]
    for seed in summary["seeds"]:
        cells = []
        for version in summary["versions"]:
            r = summary["results"][str(seed)][version]
            cells.append(f"{r['success']:.3f} [{r['low']:.3f}, {r['high']:.3f}]")
        theirs = [f"{summary['published'][m][str(seed)]:.3f}" for m in methods]
        lines.append(f"| {seed} | " + " | ".join(cells + theirs) + " |")
    pooled = summary["pooled"]
    lines += ["", "All five pooled: " + "; ".join(
        f"our {v} {pooled[v]['success']:.3f} [{pooled[v]['low']:.3f}, {pooled[v]['high']:.3f}]"
        for v in summary["versions"]) + f" ({len(summary['seeds']) * n} episodes each; the "
        "interval is descriptive: the five models meet the same reset seeds). Their curves over "
        "the same epochs, the five seeds pooled: " + "; ".join(
            f"{m} {np.mean(list(summary['published'][m].values())):.3f}" for m in methods)
        + "."]
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
        model = PublishedModel(folder / f"model{seed}.pt")
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
    means, last_epoch = published_last_epochs()
    published = {m: {str(s): v for s, v in by_seed.items()} for m, by_seed in means.items()}
    summary = {"date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
               "commit": git_commit(), "checkout_commit": checkout_commit(args.checkout),
               "quick": args.quick, "episodes": episodes, "seeds": list(seeds),
               "versions": args.versions, "eval_seed": EVAL_SEED, "results": results,
               "pooled": pooled, "published": published, "published_last_epoch": last_epoch,
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
