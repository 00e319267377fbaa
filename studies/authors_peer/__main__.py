"""`python -m studies.authors_peer --checkout PATH`: the authors' HER-CS code, unchanged but
for the adapters of peer_run.py, trained on our Fetch*-v1 into a run folder that the claims and
Fig. 2 read as a side of its own ("HER-CS, authors' code, our v1"). A stopped run resumes from
its last finished epoch when started again with the same arguments."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

from studies.authors_peer.peer_run import (
    PEER_SCHEDULE,
    PRECISIONS,
    TASK_ENV,
    PeerRun,
    checkout_commit,
    git_commit_here,
    metrics_rows,
    precision_mismatch,
    resolved_precision,
    run_peer,
    uses_cuda,
)

NEEDED = ("train.py", "rl_modules/ddpg_agent.py", "rl_modules/replay_buffer.py",
          "her_modules/her.py", "mpi_utils/normalizer.py")
"""What a checkout of their repository holds (a folder without it is refused up front)."""
DONE_FILE = "bench_done.json"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m studies.authors_peer",
                                description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--checkout", type=Path, required=True,
                   help="a checkout of ngng9957/Clustering-based-Failed-Goal-Aware-Hindsight-"
                        "Experience-Replay (outside this repository)")
    p.add_argument("--task", choices=sorted(TASK_ENV), default="pick")
    p.add_argument("--seed", type=int, default=121, help="their --seed (they used 121, 123, "
                   "125, 127, 133)")
    p.add_argument("--epochs", type=int, default=100)
    p.add_argument("--run-dir", type=Path, default=Path("runs/authors_peer"),
                   help="the folder the run folder goes in")
    p.add_argument("--name", help="the run folder's name (default <task>-v1-authors-code-s<seed>, "
                   "<task>-v1-authors-code-tf32-s<seed> where the products are TF32)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--precision", choices=PRECISIONS, default="auto",
                   help="their matrix products' arithmetic: auto (default) is torch 1.10.1's "
                        "default, TF32 on a GPU and fp32 on a CPU; tf32 on a CPU emulates a "
                        "GPU's TF32 (about twice as slow); fp32 on a GPU turns TF32 off")
    p.add_argument("--quick", action="store_true",
                   help="a check that it runs: 2 cycles an epoch, 2 test episodes")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    # the runner's own arguments, read before run_peer hands sys.argv to their train.py
    own_argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(own_argv)
    checkout = args.checkout.resolve()
    missing = [f for f in NEEDED if not (checkout / f).is_file()]
    if missing:
        parser.error(f"--checkout {args.checkout}: not a checkout of the authors' repository "
                     f"(no {', '.join(missing)})")
    if args.epochs < 1 or args.threads < 1:
        parser.error(f"--epochs {args.epochs} and --threads {args.threads} must be >= 1")
    from hercs.rl.envs import mujoco_py_problem

    problem = mujoco_py_problem()
    if problem is not None:
        print(f"python -m studies.authors_peer: Fetch*-v1 needs mujoco-py: {problem}; "
              "`make mujoco-py` installs it", file=sys.stderr)
        return 2
    cuda = uses_cuda(args.device)
    precision = resolved_precision(args.precision, cuda)  # the name says the one used
    marked = "-tf32" if precision == "tf32" else ""
    name = args.name or f"{args.task}-v1-authors-code{marked}-s{args.seed}"
    run = PeerRun(checkout=checkout, run_dir=(args.run_dir / name).resolve(), task=args.task,
                  seed=args.seed, epochs=args.epochs, threads=args.threads,
                  device=args.device, cycles=2 if args.quick else 50,
                  test_rollouts=2 if args.quick else 20, precision=precision)
    mismatch = precision_mismatch(run.run_dir, precision)  # finished or not
    if mismatch is not None:
        print(f"python -m studies.authors_peer: {mismatch}", file=sys.stderr)
        return 2
    if (run.run_dir / DONE_FILE).is_file():
        print(f"{run.run_dir}: finished ({DONE_FILE}); nothing to do")
        return 0
    started = time.monotonic()
    code = run_peer(run)
    rows = metrics_rows(run.run_dir / "metrics.csv")
    if code == 0 and rows and int(rows[-1]["epoch"]) == run.epochs:
        from hercs.apps.provenance import machine_identity

        record = {"task": run.task, "method": "her-cs", "seed": run.seed,
                  "schedule": PEER_SCHEDULE, "env_version": "v1", "env_id": run.env_id,
                  "precision": precision, "tf32_emulated": precision == "tf32" and not cuda,
                  "epochs": run.epochs, "wall_s": float(rows[-1]["wall_s"]),
                  "wall_s_this_life": round(time.monotonic() - started, 1),
                  "commit": git_commit_here(), "peer_commit": checkout_commit(checkout),
                  "command": shlex.join(["-m", "studies.authors_peer", *own_argv]),
                  "finished": datetime.now(UTC).isoformat(timespec="seconds"),
                  "machine": machine_identity()}
        (run.run_dir / DONE_FILE).write_text(json.dumps(record, indent=2))
    return code


if __name__ == "__main__":
    sys.exit(main())
