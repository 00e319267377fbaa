"""Chaos soak: a long run over mutual TLS with its actors on other "hosts", while a random
service is SIGKILLed every 60–120 s and an actor's host is cut off every few minutes.

    # as root (network namespaces, iptables); each step skips what is committed already
    python -m bench.faults.chaos --fault-free 1 2 3  # fault-free seeds of the soak's configuration
    python -m bench.faults.chaos  # the soak (chaos seed 1, training seed 1)
    python -m bench.faults.chaos --report-only  # docs/results/chaos.md from the committed runs
    python -m bench.faults.chaos --quick  # CI, ~80 s: FetchReach, 1 kill, 1 cut
    python -m bench.faults.chaos --fault-free 3 --subnet 10.127  # beside another soak (own links)

The run (`Shape`; default FetchPush, HER-EBP-CS, 20 epochs, seed 1) is `hercs up --actors 0`
on this host, listening with TLS on each link's host end, and 2 `hercs actor` each in its own
network namespace (bench.faults.netns, subnet 10.126) behind a veth link, joining across it. The
schedule (bench.faults.chaos_plan, drawn from `--chaos-seed` and recorded) SIGKILLs a replay,
learner, clusterer, evaluator (the launcher restarts them) or one of the actors (the bench
restarts it, as its host's supervisor would: bench.faults.chaos_actors) every uniform(60, 120) s,
and cuts one actor's link both ways (iptables DROP) for uniform(30, 90) s, uniform(120, 240)
s after the previous cut healed. `--targets … launcher` also kills `hercs up` itself (router
and children with it), continued with `hercs up --resume`. Every injection is recorded with
its time on the run's clock (seconds since the launch), its wall time and pid.

Resumable: the run folder, logs and the soak's state (`<work>/<run>.state.json`: the schedule,
what was injected, each actor incarnation) live under `--work` (default runs/chaos). A soak
stopped midway (Ctrl-C, SIGTERM, a crash of the bench) is continued by the same command: the
run with `hercs up --resume`, new actor incarnations, the schedule where its clock stopped
(the interruption itself is recorded as an injection). A bench that is SIGKILLed takes its
run and actors with it (the parent-death signal) but cannot remove its namespaces and
iptables chains: the next start refuses the subnet until they are gone (`ip netns del
hnf<pid>-<n>`; `iptables -D INPUT -i hnf<pid>h<n> -j HNF<pid>-<n>`, `-F`, `-X`). A finished
run gets `chaos.json` and is copied (config.yaml, metrics.csv, chaos.json) to
`--committed` (docs/results/runs/).

Asserted and reported (bench.faults.chaos_report, docs/results/chaos.{md,json}): `hercs up` exits
0 and every actor that was not killed on purpose exits 0; every epoch once in metrics.csv;
every episode an actor logged as acked is in the episode log and none is stored twice
(bench.faults.net_measure); policy lag p50/p95, inserts/s, epoch median/max; per injection the
time until the target was back, the next insert and the next epoch; and the success curve
against the envelope of the fault-free seeds (bench.faults.chaos_envelope).
"""

from __future__ import annotations

import argparse
import contextlib
import ipaddress
import json
import os
import re
import shutil
import signal
import sys
import tempfile
import time
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench.faults.chaos_actors import Incarnation, RemoteActors
from bench.faults.chaos_plan import QUICK_PLAN, TARGETS, ChaosPlan, Event
from bench.faults.chaos_report import measure_soak, write_report
from bench.faults.chaos_state import QUICK_SHAPE, Shape, SoakState, new_state
from bench.faults.netns import Host, hosts, problem
from bench.faults.remote_actor import ACTOR_EXIT_S, free_port, sigterm_as_exit
from bench.faults.service_kills import EPOCH, Up
from hercs.apps.certs import make_certs
from hercs.run.rundir import CONFIG, RunDir

REPO = Path(__file__).resolve().parents[2]
WORK = REPO / "runs" / "chaos"
COMMITTED = REPO / "docs" / "results" / "runs"
SUBNET = "10.126"
"""The soak's links (bench.faults.net_faults and its test use 10.125; one may run beside it)."""
NEVER = re.compile(r"(?!)")
TICK_S = 1.0
"""The loop's longest wait: heals, restarts and kills are this punctual."""
MAX_RESTARTS = 1000
"""`launch.max_restarts` of a soak's run. The default (5 deaths of one child without 5 min of
uptime in between) would end a soak that happens to draw one service 6 times in a row; the
give-up rule is tested elsewhere (tests/integration/test_launcher.py), not here."""


def _cmdline(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
    except OSError:
        return []


class Soak:
    """One run under a schedule (an empty one for a fault-free seed): launch, inject, heal,
    supervise the remote actors, until `hercs up` ends."""

    def __init__(self, state: SoakState, *, links: list[Host], certs: Path, work: Path,
                 shape: Shape) -> None:
        self.state, self.shape, self.links, self.certs = state, shape, links, certs
        self.run_root = work / "runs"
        self.run_dir = self.run_root / state.name
        self.run_root.mkdir(parents=True, exist_ok=True)
        self.state_path = work / f"{state.name}.state.json"
        self.port = free_port()
        self.offset, self.started = state.elapsed_s, time.monotonic()
        self.events = [Event(**e) for e in state.events]
        self.history = [Incarnation(**a) for a in state.actors]
        self.actors = RemoteActors(links, endpoint=f"tls/HOST:{self.port}", run=state.name,
                                   certs=certs, out=self.run_root, history=self.history)
        self.cuts: dict[str, tuple[float, dict[str, Any]]] = {}
        """Cut hosts by actor id: (heal due on the run's clock, the injection's record)."""
        self.hosts = dict(zip(self.actors.idents, links, strict=True))
        self.up: Up | None = None

    def now(self) -> float:
        return self.offset + time.monotonic() - self.started

    def _clocked(self, up: Up) -> list[tuple[float, str]]:
        return [(round(self.offset + at - self.started, 2), line) for at, line in up.seen]

    def save(self) -> None:
        self.state.elapsed_s = round(self.now(), 2)
        self.state.actors = [asdict(i) for i in self.history]
        self.state.notes = [*dict.fromkeys(self.state.notes + self.actors.notes)]
        live = self._clocked(self.up) if self.up is not None else []
        saved, self.state.progress = self.state.progress, self.state.progress + live
        self.state.save(self.state_path)
        self.state.progress = saved

    # ------------------------------------------------------------------ hercs up
    def launch(self, *, resume: bool) -> Up:
        common = ["--actors", "0", "--tls-dir", str(self.certs),
                  *[a for h in self.links for a in ("--listen", f"tls/{h.host_ip}:{self.port}")],
                  "--set", f"training.epochs={self.shape.epochs}",
                  "--set", f"launch.max_restarts={MAX_RESTARTS}"]
        argv = [sys.executable, "-m", "hercs.apps.cli", "up"]
        if resume:
            argv += ["--resume", str(self.run_dir), *common]
        else:
            s = self.shape
            argv += ["--task", s.task, "--method", s.method, "--seed", str(s.seed), "--run",
                     self.state.name, "--run-dir", str(self.run_root), *common,
                     *[a for item in s.sets for a in ("--set", item)]]
        self.state.launches.append(f"{self.now():.0f} s: {' '.join(argv[1:])}")
        return Up(argv, self.run_root / f"{self.state.name}.out")

    def _child(self, ident: str) -> int | None:
        """The pid of `hercs up`'s child `ident` if it is running now: the latest pid the
        launcher printed for it, still a process whose command line names this run's
        config and that id (so a pid the kernel has reused is never signalled)."""
        assert self.up is not None
        pid = self.up.pids.get(ident)
        if pid is None:
            return None
        argv = _cmdline(pid)
        ours = str(RunDir(self.run_dir).config) in argv and ident in argv
        return pid if ours else None

    def _stop_up(self, sig: int) -> None:
        """Signal the launcher and wait until it and its children are gone (they die with
        it: PR_SET_PDEATHSIG, hercs/apps/child_process.py)."""
        assert self.up is not None
        children = [pid for ident in self.up.pids if (pid := self._child(ident)) is not None]
        with contextlib.suppress(ProcessLookupError):
            self.up.proc.send_signal(sig)
        status = self.up.finish(120.0)
        self.state.up_exits.append(status)
        deadline = time.monotonic() + 30.0
        while any(self._child_alive(pid) for pid in children) and time.monotonic() < deadline:
            time.sleep(0.1)  # the kernel's SIGKILL to the children: nothing to await
        self.state.progress += self._clocked(self.up)
        self.up = None

    def _due(self, event: Event, now: float) -> bool:
        """On the clock, or (an epoch-gated plan) once its epoch is recorded."""
        if event.after_epoch:
            return self._epochs_recorded() >= event.after_epoch
        return event.at_s <= now

    def _epochs_recorded(self) -> int:
        """The last epoch `hercs up` has printed, over every launch of this soak."""
        live = [] if self.up is None else self.up.seen
        return max((int(m["epoch"]) for _, line in (*self.state.progress, *live)
                    if (m := EPOCH.match(line))), default=0)

    def _child_alive(self, pid: int) -> bool:
        return str(RunDir(self.run_dir).config) in _cmdline(pid)

    # ----------------------------------------------------------------- injections
    def inject(self, event: Event) -> None:
        now = self.now()
        record: dict[str, Any] = {
            "planned_at_s": event.at_s, "at_s": round(now, 2), "kind": event.kind,
            "target": event.target, "duration_s": event.duration_s,
            "wall_s": round(time.time(), 3),
            "wall": datetime.now(UTC).isoformat(timespec="seconds"), "pid": None,
            "outcome": "done"}
        if event.kind == "cut":
            self.hosts[event.target].cut(both_ways=True)
            self.cuts[event.target] = (now + event.duration_s, record)
        elif event.target == "launcher":
            assert self.up is not None
            record["pid"] = self.up.proc.pid
            self._stop_up(signal.SIGKILL)
            self.up = self.launch(resume=True)
        elif event.target in self.actors.hosts:
            record["pid"] = self.actors.kill(event.target, now)
        else:
            pid = self._child(event.target)
            if pid is not None:
                os.kill(pid, signal.SIGKILL)
            record["pid"] = pid
        if record["pid"] is None and event.kind == "kill":
            record["outcome"] = "skipped: not running (between a death and its restart)"
        self.state.injections.append(record)
        shown = "" if record["pid"] is None else f" (pid {record['pid']})"
        outcome = "" if record["outcome"] == "done" else f" — {record['outcome']}"
        print(f"chaos: {now:7.1f} s  {event.describe()}{shown}{outcome}", flush=True)

    def heal(self, ident: str) -> None:
        _, record = self.cuts.pop(ident)
        self.hosts[ident].heal(both_ways=True)
        record["healed_at_s"] = round(self.now(), 2)
        record["healed_wall_s"] = round(time.time(), 3)
        print(f"chaos: {record['healed_at_s']:7.1f} s  healed {ident}'s link", flush=True)

    def _note_restarts(self, restarted: list[tuple[str, float]]) -> None:
        for ident, at in restarted:
            for record in reversed(self.state.injections):
                if record["target"] == ident and record["kind"] == "kill":
                    record.setdefault("restarted_at_s", round(at, 2))
                    break

    # ----------------------------------------------------------------------- run
    def run(self) -> None:
        """Launch (or resume) and inject until `hercs up` ends; the state is saved after each
        injection and on the way out, finished or not."""
        resume = RunDir(self.run_dir).config.is_file()
        if resume and not (self.state.injections
                           and self.state.injections[-1]["kind"] == "interrupted"):
            self.state.injections.append({  # the bench died without its `finally` (SIGKILL)
                "at_s": round(self.now(), 2), "kind": "interrupted", "target": "bench",
                "wall": datetime.now(UTC).isoformat(timespec="seconds"),
                "outcome": "the soak stopped without saving its end (its last save is here)"})
        for incarnation in self.history:
            if incarnation.exit is None and not incarnation.killed_by:  # died with that bench
                incarnation.killed_by = "bench stopped"
        for record in self.state.injections:
            if record["kind"] == "cut" and "healed_at_s" not in record:
                record["outcome"] = "done; ended with the bench (its namespace went with it)"
        if resume:
            self.state.injections.append({
                "at_s": round(self.now(), 2), "kind": "resume", "target": "bench",
                "wall": datetime.now(UTC).isoformat(timespec="seconds"),
                "outcome": "the soak was stopped; continued with hercs up --resume"})
        self.state.loads.append(os.getloadavg()[0])
        last_line, last_count, last_save = self.now(), 0, self.now()
        try:
            self.up = self.launch(resume=resume)
            self.actors.start_all(self.now())
            while True:
                now = self.now()
                for ident in [i for i, (due, _) in self.cuts.items() if due <= now]:
                    self.heal(ident)
                self._note_restarts(self.actors.tend(now))
                while (self.state.next_event < len(self.events)
                       and self._due(self.events[self.state.next_event], now)):
                    self.inject(self.events[self.state.next_event])
                    self.state.next_event += 1
                    self.save()
                if len(self.up.seen) != last_count:
                    last_line, last_count = now, len(self.up.seen)
                elif now - last_line > self.shape.stall_s:
                    self.state.notes.append(f"no line from hercs up for {self.shape.stall_s:g}"
                                            f" s at {now:.0f} s; the run was given up")
                    self._stop_up(signal.SIGTERM)
                    break
                if now - last_save > 30.0:
                    self.save()
                    last_save = now
                try:
                    self.up.wait_for(NEVER, TICK_S)
                except TimeoutError:
                    continue
                except RuntimeError:  # its output ended: the run is over
                    self.state.progress += self._clocked(self.up)
                    self.state.up_exits.append(self.up.finish(120.0))
                    self.up = None
                    break
            for ident in list(self.cuts):  # an actor behind a cut could not hear the end
                self.heal(ident)
            self.actors.stop_all(ACTOR_EXIT_S)
            self.state.finished = True
        finally:
            if not self.state.finished:
                self.state.injections.append({
                    "at_s": round(self.now(), 2), "kind": "interrupted", "target": "bench",
                    "wall": datetime.now(UTC).isoformat(timespec="seconds"),
                    "outcome": f"the soak stopped: {sys.exc_info()[1]!r}"})
                for ident in list(self.cuts):
                    self.heal(ident)
                self.actors.kill_all(self.now())
                if self.up is not None:
                    self._stop_up(signal.SIGTERM)
            self.state.loads.append(os.getloadavg()[0])
            self.save()


def soak(shape: Shape, *, chaos_seed: int | None, plan: ChaosPlan | None, work: Path,
         committed: Path | None, quick: bool, subnet: str = SUBNET) -> dict[str, Any]:
    """Run (or continue, or only read back) one soak; its record (chaos.json). Soaks on
    different subnets may run side by side (each its own namespaces, chains and certificates)."""
    name = shape.run_name(chaos_seed)
    state_path = work / f"{name}.state.json"
    done = None if committed is None else committed / name / "chaos.json"
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
    run_dir = work / "runs" / name
    (run_dir / "chaos.json").write_text(json.dumps(record, indent=1) + "\n")
    if committed is not None:
        target = committed / name
        target.mkdir(parents=True, exist_ok=True)
        for item in (CONFIG, "metrics.csv", "chaos.json"):
            if (run_dir / item).is_file():
                shutil.copyfile(run_dir / item, target / item)
        print(f"chaos: {name}: committed files in {target} (commit them)", flush=True)
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
