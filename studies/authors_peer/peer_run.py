"""One run of the authors' `train.py` on our v1 stack, written in our run format.

Their algorithm runs as published, with only the stand-ins and settings listed in
docs/results/README.md; their class is subclassed only to record each epoch's test success in
our `metrics.csv` and to snapshot the state at an epoch's end, so that a stopped run resumes.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import importlib
import json
import os
import random
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from studies.authors_peer import PEER_SCHEDULE
from studies.authors_peer.old_gym import gym_module
from studies.authors_peer.single_mpi import mpi4py_module

TASK_ENV = {"push": "FetchPush-v1", "pick": "FetchPickAndPlace-v1", "slide": "FetchSlide-v1",
            "reach": "FetchReach-v1"}
KMEANS_N_INIT = 10
METRICS_COLUMNS = ("epoch", "env_steps", "episodes", "updates", "success_rate", "wall_s",
                   "cluster_fitted", "failed_goals", "cluster_sizes")
STATE_DIR = "peer_state"
"""The run folder's snapshot of the agent after its last finished epoch (scratch: not committed)."""
SCRATCH_DIR = "peer_scratch"
"""Their code's working directory: it writes `figures/` and `saved_models/` relative to it."""


@dataclass(frozen=True)
class PeerRun:
    checkout: Path
    run_dir: Path
    task: str
    seed: int
    epochs: int
    threads: int = 1
    device: str = "auto"  # auto: CUDA where torch has it (their --cuda default), else CPU
    cycles: int = 50  # their --n-cycles; smaller only for a quick check
    test_rollouts: int = 20  # their --n-test-rollouts
    precision: str = "auto"  # PRECISIONS ("auto": torch 1.10.1's default on the device)

    @property
    def env_id(self) -> str:
        return TASK_ENV[self.task]


PRECISIONS = ("auto", "fp32", "tf32")
"""The arithmetic of their matrix products: "auto" is what torch 1.10.1, their README's, did by
default (TF32 on a CUDA GPU, which we take to be Ampere or newer; fp32 on a CPU); "tf32" on a
CPU emulates it (hercs/learner/tf32.py: every product of their update, target and rollouts);
"fp32" on a GPU turns TF32 off."""


def resolved_precision(precision: str, cuda: bool) -> str:
    """"fp32" or "tf32": `precision` with "auto" resolved for the device."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision {precision!r}: must be one of {', '.join(PRECISIONS)}")
    if precision == "auto":
        return "tf32" if cuda else "fp32"
    return precision


def uses_cuda(device: str) -> bool:
    """Whether a run on `device` ("auto", "cpu", "cuda") trains on a CUDA GPU."""
    import torch

    return torch.cuda.is_available() if device == "auto" else device == "cuda"


def recorded_precision(run_dir: Path) -> str | None:
    """The arithmetic `run_dir` trained in, as its config.yaml records it (None: no config)."""
    path = run_dir / "config.yaml"
    if not path.is_file():
        return None
    config = yaml.safe_load(path.read_text()) or {}
    return str((config.get("learner") or {}).get("precision", "fp32"))


def precision_mismatch(run_dir: Path, precision: str) -> str | None:
    """Why `run_dir` cannot be resumed in `precision` (its config.yaml says another), or None:
    a run trained in one arithmetic and continued in another would be neither."""
    before = recorded_precision(run_dir)
    if before is None or before == precision:
        return None
    return (f"{run_dir}: trained in {before} (its config.yaml's learner.precision), asked to "
            f"continue in {precision}; give --precision {before}, or another --name")


def make_gymnasium_env(name: str, **kwargs: Any) -> Any:
    """gymnasium-robotics' `name` made the way hercs makes it (mujoco-py prepared for v1),
    without hercs' indexed reads: their code steps the env as published."""
    import gymnasium as gym

    from hercs.rl.envs import register_envs

    register_envs()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*(is out of date|mujoco-py bindings)")
        return gym.make(name, disable_env_checker=True, **kwargs)


def install_stand_ins(checkout: Path) -> None:
    """Make `import gym`, `import mpi4py` and their own packages resolve for their code."""
    mpi = mpi4py_module()
    sys.modules["mpi4py"] = mpi
    sys.modules["mpi4py.MPI"] = mpi.MPI  # type: ignore[attr-defined]
    sys.modules["gym"] = gym_module(make_gymnasium_env)
    sys.path.insert(0, str(checkout))


def their_args(run: PeerRun) -> list[str]:
    """train.py's command line for this run (its other flags keep their defaults)."""
    return ["train.py", "--env-name", run.env_id, "--seed", str(run.seed),
            "--n-epochs", str(run.epochs), "--n-cycles", str(run.cycles),
            "--n-test-rollouts", str(run.test_rollouts)]


def checkout_commit(checkout: Path) -> str:
    from hercs.apps.provenance import git_commit

    return git_commit(checkout)


def git_commit_here() -> str:
    """The hercs commit this runner runs from."""
    from hercs.apps.provenance import git_commit

    return git_commit()


# --------------------------------------------------------------------------- the run files

def write_config(run: PeerRun, args: Any, commit: str, precision: str) -> None:
    """config.yaml: what the claims group by (task, env, method, seed, schedule, and
    `precision`, "fp32" or "tf32"), their
    arguments as train.py resolved them, and the hercs commit the run started from (kept
    through resumes; bench_done.json gets the finishing one)."""
    path = run.run_dir / "config.yaml"
    old = yaml.safe_load(path.read_text()) if path.is_file() else None
    started = ((old or {}).get("peer") or {}).get("started_commit") or git_commit_here()
    arithmetic = {("tf32", False): ["TF32 products emulated (hercs/learner/tf32.py)"],
                  ("fp32", True): ["TF32 off (torch.backends' allow_tf32 False)"]}
    config = {
        "run": {"method": "her-cs", "seed": run.seed, "name": run.run_dir.name,
                "run_dir": str(run.run_dir.parent)},
        "task": {"name": run.task, "env_version": "v1"},
        "training": {"schedule": PEER_SCHEDULE, "epochs": run.epochs,
                     "cycles_per_epoch": args.n_cycles,
                     "episodes_per_cycle": args.num_rollouts_per_mpi,
                     "minibatches_per_cycle": args.n_batches},
        "learner": {"precision": precision},
        "peer": {"code": "ngng9957/Clustering-based-Failed-Goal-Aware-Hindsight-Experience-"
                         "Replay", "checkout": str(run.checkout), "commit": commit,
                 "started_commit": started,
                 "adapted": ["gym 0.17 API over gymnasium-robotics", "one-rank MPI",
                             f"device {'cuda' if args.cuda else 'cpu'}",
                             f"KMeans n_init={KMEANS_N_INIT}", f"torch threads {run.threads}",
                             *arithmetic.get((precision, bool(args.cuda)), [])],
                 "args": {k: (v if isinstance(v, (int, float, str, bool)) else str(v))
                          for k, v in sorted(vars(args).items())}},
    }
    path.write_text(yaml.safe_dump(config, sort_keys=False))


def metrics_rows(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def rewrite_metrics(path: Path, rows: list[dict[str, str]]) -> None:
    tmp = path.with_suffix(".tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=METRICS_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)


# ------------------------------------------------------------------------------ snapshots

def _normaliser_arrays(norm: Any, prefix: str) -> dict[str, np.ndarray]:
    keys = ("local_sum", "local_sumsq", "local_count", "total_sum", "total_sumsq",
            "total_count", "mean", "std")
    return {f"{prefix}.{k}": np.asarray(getattr(norm, k)) for k in keys}


def save_snapshot(agent: Any, folder: Path, *, epoch: int, wall_s: float) -> None:
    """The agent's whole training state after `epoch`: networks and optimisers (torch tensors),
    normalisers, the filled part of the buffer, the failed goals and cluster centres, and every
    random stream (Python's, NumPy's, torch's, the env's). Arrays and JSON only: no pickle."""
    import torch

    tmp = folder.with_name(folder.name + ".tmp")
    tmp.mkdir(parents=True, exist_ok=True)
    nets = {name: getattr(agent, name).state_dict() for name in
            ("actor_network", "critic_network", "actor_target_network",
             "critic_target_network", "actor_optim", "critic_optim")}
    nets["torch_rng"] = torch.get_rng_state()
    torch.save(nets, tmp / "nets.pt")
    buf = agent.buffer
    n = int(buf.current_size)
    arrays = {f"buffer.{k}": v[:n] for k, v in buf.buffers.items()}
    arrays.update(_normaliser_arrays(agent.o_norm, "o_norm"))
    arrays.update(_normaliser_arrays(agent.g_norm, "g_norm"))
    arrays["fgs"] = np.asarray(buf.fgs, np.float64).reshape(len(buf.fgs), -1)
    if hasattr(buf.cluster, "cluster_centers_"):
        arrays["cluster_centers"] = buf.cluster.cluster_centers_
    np_state = np.random.get_state()
    arrays["np_rng_keys"] = np_state[1]
    np.savez(tmp / "arrays.npz", **arrays)
    py_state = random.getstate()
    meta = {"epoch": epoch, "wall_s": wall_s, "current_size": n,
            "n_transitions_stored": int(buf.n_transitions_stored), "idx_fg": int(buf.idx_fg),
            "np_rng": [np_state[0], int(np_state[2]), int(np_state[3]), float(np_state[4])],
            "py_rng": [py_state[0], list(py_state[1]), py_state[2]],
            "env_rng": agent.env.env.unwrapped.np_random.bit_generator.state}
    (tmp / "meta.json").write_text(json.dumps(meta, default=int))
    old = folder.with_name(folder.name + ".old")
    if folder.exists():
        os.replace(folder, old)
    os.replace(tmp, folder)  # a stop between the two renames: recover_snapshot takes the old one
    _remove_folder(old)


def _remove_folder(folder: Path) -> None:
    if folder.is_dir():
        for f in folder.iterdir():
            f.unlink()
        folder.rmdir()


def recover_snapshot(folder: Path) -> None:
    """Put `folder` back in order after a stop inside `save_snapshot`: a half-written `.tmp`
    is dropped; the `.old` snapshot is dropped where the new one is in place, and becomes the
    snapshot again where the stop came between the two renames (without this the run would
    start over from epoch 0, and the next save would fail on the leftover `.old`)."""
    _remove_folder(folder.with_name(folder.name + ".tmp"))
    old = folder.with_name(folder.name + ".old")
    if folder.exists():
        _remove_folder(old)
    elif old.is_dir():
        os.replace(old, folder)


def snapshot_epoch(folder: Path) -> int:
    """The epoch the snapshot in `folder` was taken after (0: none)."""
    meta = folder / "meta.json"
    return int(json.loads(meta.read_text())["epoch"]) if meta.is_file() else 0


def restore_cluster_centres(kmeans: Any, centers: np.ndarray) -> None:
    """Give their k-means object the saved `centers`, label i still centre i (their share rule
    reads labels in order), and leave its settings as they were, so that every later refit
    starts as theirs does (k-means++ draws, KMEANS_N_INIT tries), not from these centres."""
    settings = {k: v for k, v in kmeans.get_params().items() if k in ("init", "n_init")}
    # fitting on the centres themselves, started at them, returns them in their order
    kmeans.set_params(init=centers, n_init=1)
    kmeans.fit(centers)
    kmeans.set_params(**settings)


def load_snapshot(agent: Any, folder: Path) -> dict[str, Any]:
    """Put the snapshot in `folder` back into `agent` (made as their launch() makes it);
    returns its meta (epoch, wall_s)."""
    import torch

    meta = json.loads((folder / "meta.json").read_text())
    nets = torch.load(folder / "nets.pt", weights_only=True)
    for name, state in nets.items():
        if name != "torch_rng":
            getattr(agent, name).load_state_dict(state)
    with np.load(folder / "arrays.npz", allow_pickle=False) as arrays:
        buf = agent.buffer
        n = int(meta["current_size"])
        for k in buf.buffers:
            buf.buffers[k][:n] = arrays[f"buffer.{k}"]
        buf.current_size = n
        buf.n_transitions_stored = int(meta["n_transitions_stored"])
        buf.fgs = arrays["fgs"].tolist()
        buf.idx_fg = int(meta["idx_fg"])
        for prefix, norm in (("o_norm", agent.o_norm), ("g_norm", agent.g_norm)):
            for key in ("local_sum", "local_sumsq", "local_count", "total_sum", "total_sumsq",
                        "total_count", "mean", "std"):
                setattr(norm, key, arrays[f"{prefix}.{key}"].copy())
        if "cluster_centers" in arrays:
            restore_cluster_centres(buf.cluster, arrays["cluster_centers"])
        keys = arrays["np_rng_keys"]
    name, pos, has_gauss, gauss = meta["np_rng"]
    np.random.set_state((name, keys, pos, has_gauss, gauss))
    version, internal, gauss_next = meta["py_rng"]
    random.setstate((version, tuple(internal), gauss_next))
    torch.set_rng_state(nets["torch_rng"])
    agent.env.env.unwrapped.np_random.bit_generator.state = meta["env_rng"]
    agent.env._seed = None  # their launch() seeded it; the restored stream replaces that
    return meta


# ----------------------------------------------------------------------------------- run

def run_peer(run: PeerRun) -> int:
    """Train (or resume) `run`; returns the exit code. One metrics row per finished epoch.
    The caller has refused a run folder trained in another precision (`precision_mismatch`,
    before it reads the folder's finished record)."""
    os.environ["OMP_NUM_THREADS"] = os.environ["MKL_NUM_THREADS"] = str(run.threads)
    os.environ["IN_MPI"] = "1"  # what their __main__ sets
    import torch
    from sklearn.cluster import KMeans

    torch.set_num_threads(run.threads)
    cuda = uses_cuda(run.device)
    precision = resolved_precision(run.precision, cuda)
    install_stand_ins(run.checkout)
    train = importlib.import_module("train")
    replay_buffer = importlib.import_module("rl_modules.replay_buffer")
    replay_buffer.KMeans = functools.partial(KMeans, n_init=KMEANS_N_INIT)  # type: ignore[attr-defined]

    run.run_dir.mkdir(parents=True, exist_ok=True)
    scratch = run.run_dir / SCRATCH_DIR
    (scratch / "figures").mkdir(parents=True, exist_ok=True)
    state_dir = run.run_dir / STATE_DIR
    metrics_path = run.run_dir / "metrics.csv"
    recover_snapshot(state_dir)
    done_epochs = snapshot_epoch(state_dir)
    if done_epochs >= run.epochs:
        print(f"{run.run_dir.name}: already at epoch {done_epochs} of {run.epochs}")
        return 0
    # rows past the snapshot were written by a life that stopped before its snapshot
    rewrite_metrics(metrics_path, [r for r in metrics_rows(metrics_path)
                                   if int(r["epoch"]) <= done_epochs])

    sys.argv = their_args(run)
    args = train.get_args()
    args.cuda = cuda
    if cuda:  # torch 1.10's default: TF32 on an Ampere-or-newer GPU (theirs unpublished)
        torch.backends.cuda.matmul.allow_tf32 = precision == "tf32"
        torch.backends.cudnn.allow_tf32 = precision == "tf32"
    args.save_dir = str(scratch / "saved_models") + "/"
    write_config(run, args, checkout_commit(run.checkout), precision)
    steps_per_epoch = args.n_cycles * args.num_rollouts_per_mpi * 50
    started = time.monotonic()

    class RecordedAgent(train.ddpg_agent):  # type: ignore[name-defined,misc]
        """Their agent; each evaluation also becomes a metrics row and a snapshot."""

        epoch = done_epochs
        wall_before = 0.0

        def learn(self) -> None:
            if done_epochs:
                meta = load_snapshot(self, state_dir)
                type(self).wall_before = float(meta["wall_s"])
                print(f"{run.run_dir.name}: resumed after epoch {done_epochs}", flush=True)
            self.args.n_epochs = run.epochs - done_epochs
            super().learn()

        def _eval_agent(self) -> float:
            success = super()._eval_agent()
            type(self).epoch += 1
            epoch = type(self).epoch
            wall = type(self).wall_before + time.monotonic() - started
            buf = self.buffer
            fitted = hasattr(buf.cluster, "cluster_centers_")
            sizes = ""
            if fitted:
                labels = buf.cluster.predict(buf.buffers["ag"][:buf.current_size, -1, :])
                sizes = ";".join(str(c) for c in np.bincount(labels, minlength=8))
            row = {"epoch": epoch, "env_steps": epoch * steps_per_epoch,
                   "episodes": epoch * args.n_cycles * args.num_rollouts_per_mpi,
                   "updates": epoch * args.n_cycles * args.n_batches,
                   "success_rate": f"{success:.4f}", "wall_s": f"{wall:.1f}",
                   "cluster_fitted": int(fitted), "failed_goals": len(buf.fgs),
                   "cluster_sizes": sizes}
            rewrite_metrics(metrics_path, [*metrics_rows(metrics_path), row])
            save_snapshot(self, state_dir, epoch=epoch, wall_s=wall)
            print(f"{run.run_dir.name}: epoch {epoch}/{run.epochs} success {success:.3f} "
                  f"({wall:.0f} s)", flush=True)
            return success

    train.ddpg_agent = RecordedAgent
    arithmetic: contextlib.AbstractContextManager[Any] = contextlib.nullcontext()
    if precision == "tf32" and not args.cuda:
        from hercs.learner.tf32 import TF32Products

        arithmetic = TF32Products()  # every product their code makes, as a GPU's TF32 would
    with contextlib.chdir(scratch), arithmetic:
        train.launch(args)
    return 0
