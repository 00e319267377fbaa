"""Chaos soak: a whole run over mutual TLS, actors on other "hosts", under random kills and cuts.

    python -m bench.faults.chaos  # as root: the soak (--chaos-seed 1, training seed 1); resumable

Also `--fault-free SEED ...`, `--report-only` and `--quick` (CI, ~80 s). Schedule, resume,
clean-up and what is asserted: docs/FAULTS.md, "The chaos soak"; docs/results/chaos.md."""

from __future__ import annotations

import argparse
import ipaddress
import json
import shutil
import sys
import tempfile
from dataclasses import asdict
from pathlib import Path
from typing import Any

from bench.common import REPO
from bench.faults.chaos_plan import QUICK_PLAN, TARGETS, ChaosPlan
from bench.faults.chaos_record import RECORD, measure_soak
from bench.faults.chaos_report import write_report
from bench.faults.chaos_soak import Soak
from bench.faults.chaos_state import QUICK_SHAPE, Shape, SoakState, new_state
from bench.faults.netns import hosts, problem
from bench.faults.remote_actor import sigterm_as_exit
from hercs.apps.deploy.certs import make_certs
from hercs.run.rundir import RunDir

WORK = REPO / "runs" / "chaos"
COMMITTED = REPO / "docs" / "results" / "runs"
SUBNET = "10.126"
"""The soak's links (bench.faults.net_faults and its test use 10.125; one may run beside it)."""


def soak(shape: Shape, *, chaos_seed: int | None, plan: ChaosPlan | None, work: Path,
         committed: Path | None, quick: bool, subnet: str = SUBNET) -> dict[str, Any]:
    """Run (or continue, or only read back) one soak; its record (chaos.json). Soaks on
    different subnets may run side by side (each its own namespaces, chains and certificates)."""
    name = shape.run_name(chaos_seed)
    state_path = work / f"{name}.state.json"
    done = None if committed is None else committed / name / RECORD
    if done is not None and done.is_file() and not state_path.is_file():
        print(f"chaos: {name}: finished and committed ({done.parent})", flush=True)
        return dict(json.loads(done.read_text()))
    work.mkdir(parents=True, exist_ok=True)
    state = new_state(shape, chaos_seed=chaos_seed, plan=plan, quick=quick)
    if state_path.is_file():
        saved = SoakState.load(state_path)
        if (saved.shape, saved.plan) != (state.shape, state.plan):
            raise SystemExit(f"chaos: {state_path} is a soak of another shape or schedule "
                             f"({saved.shape}, {saved.plan}); give the same options to continue "
                             "it, or another --work (or remove it) to start afresh")
        state = saved
        print(f"chaos: {name}: {'finished earlier' if state.finished else 'continuing'} "
              f"({state_path})", flush=True)
    if not state.finished:
        with sigterm_as_exit(), hosts(shape.actors, subnet=subnet) as links:
            # the certificates name the link addresses, so each subnet has its own
            certs = work / ("certs" if subnet == SUBNET else f"certs-{subnet}")
            if not (certs / "ca.pem").is_file():
                make_certs(certs, hosts=[host.host_ip for host in links])
            Soak(state, links=links, certs=certs, work=work, shape=shape).run()
    record = measure_soak(state, run_root=work / "runs")
    run = RunDir(work / "runs" / name)
    (run.path / RECORD).write_text(json.dumps(record, indent=1) + "\n")
    if committed is not None:
        target = RunDir(committed / name)
        target.path.mkdir(parents=True, exist_ok=True)
        for source, copy in ((run.config, target.config), (run.metrics, target.metrics),
                             (run.path / RECORD, target.path / RECORD)):
            if source.is_file():
                shutil.copyfile(source, copy)
        print(f"chaos: {name}: committed files in {target.path} (commit them)", flush=True)
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--task", default=Shape.task)
    parser.add_argument("--method", default=Shape.method)
    parser.add_argument("--epochs", type=int, default=Shape.epochs)
    parser.add_argument("--seed", type=int, default=Shape.seed, help="the soak's training seed")
    parser.add_argument("--chaos-seed", type=int, default=1, help="the schedule's seed")
    parser.add_argument("--set", dest="sets", action="append", default=[],
                        metavar="SECTION.FIELD=VALUE", help="passed to hercs up (and to the "
                        "fault-free seeds: give both the same)")
    parser.add_argument("--targets", nargs="+", choices=TARGETS, default=list(ChaosPlan.targets))
    for flag, default, what in (("--kill-gap", ChaosPlan.kill_gap_s, "between two kills"),
                                ("--cut-gap", ChaosPlan.cut_gap_s, "from a heal to the next cut"),
                                ("--cut-s", ChaosPlan.cut_s, "how long a cut lasts")):
        parser.add_argument(flag, nargs=2, type=float, default=list(default),
                            metavar=("LOW", "HIGH"), help=f"seconds {what}, drawn uniformly "
                            f"(default {default[0]:g} {default[1]:g})")
    parser.add_argument("--fault-free", nargs="+", type=int, metavar="SEED",
                        help="run these training seeds without faults (the envelope), not the "
                        "soak")
    parser.add_argument("--baseline", nargs="+", type=Path, metavar="RUN_DIR",
                        help="the fault-free runs of the envelope (default: the committed "
                        "nofault-<task>-<method>-s* folders)")
    parser.add_argument("--window", type=int, default=3, help="epochs the success curves are "
                        "smoothed over before the envelope check")
    parser.add_argument("--work", type=Path, help=f"run folders and soak states (default "
                        f"{WORK.relative_to(REPO)}; a temp folder with --quick)")
    parser.add_argument("--committed", type=Path, help="where finished runs' small files go "
                        f"(default {COMMITTED.relative_to(REPO)}; none with --quick)")
    parser.add_argument("--out", type=Path, help="where chaos.md and chaos.json go (default "
                        "docs/results; a temp folder with --quick)")
    parser.add_argument("--report-only", action="store_true")
    parser.add_argument("--subnet", default=SUBNET, help="the /16 the actors' links use, as "
                        f"A.B (default {SUBNET}); another lets a second soak run beside this one")
    parser.add_argument("--quick", action="store_true", help="CI: FetchReach 5 × 8 cycles, "
                        "one remote actor killed, one host cut for 12 s")
    args = parser.parse_args(argv)
    try:
        ipaddress.IPv4Network(f"{args.subnet}.0.0/16")
    except ValueError:
        parser.error(f"--subnet {args.subnet!r}: give the first two octets of a /16, e.g. 10.127")
    if not args.report_only and (why := problem(args.subnet)) is not None:
        print(f"chaos: cannot run here: {why}", file=sys.stderr)
        return 2
    tmp = tempfile.TemporaryDirectory(prefix="hercs-chaos-")
    if args.quick:
        shape, plan = QUICK_SHAPE, QUICK_PLAN
    else:
        shape = Shape(task=args.task, method=args.method, epochs=args.epochs, seed=args.seed,
                      sets=tuple(args.sets))
        try:
            plan = ChaosPlan(kill_gap_s=tuple(args.kill_gap), cut_gap_s=tuple(args.cut_gap),
                             cut_s=tuple(args.cut_s), targets=tuple(args.targets))
        except ValueError as exc:
            parser.error(str(exc))
    work = args.work or (Path(tmp.name) if args.quick else WORK)
    committed = args.committed or (None if args.quick else COMMITTED)
    out = args.out or (Path(tmp.name) if args.quick else REPO / "docs" / "results")
    records = []
    if not args.report_only:
        for seed in args.fault_free or []:
            free = Shape(**{**asdict(shape), "seed": seed})
            records.append(soak(free, chaos_seed=None, plan=None, work=work,
                                committed=committed, quick=args.quick, subnet=args.subnet))
        if not args.fault_free:
            records.append(soak(shape, chaos_seed=args.chaos_seed, plan=plan, work=work,
                                committed=committed, quick=args.quick, subnet=args.subnet))
    command = "python -m bench.faults.chaos " + " ".join(sys.argv[1:] if argv is None else argv)
    ok = write_report(records, task=shape.task, method=shape.method, work=work, committed=committed,
                      baselines=args.baseline, window=args.window, out=out,
                      command=command.strip())
    tmp.cleanup()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
