"""Network faults between hosts: a real `hercs up` run over mutual TLS, one fault per run.

    python -m bench.faults.net_faults  # as root, ~15 min: 8 settings, FetchReach, 2 actors

Actors sit in network namespaces (bench.faults.netns). Settings and method: docs/FAULTS.md,
"Network faults"; results: docs/results/net_faults.{md,json}."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from bench.common import REPO, git_commit, table_with_notes
from bench.faults.delay_relay import DelayRelay
from bench.faults.net_measure import NetResult, measure
from bench.faults.netns import Host, hosts, problem
from bench.faults.remote_actor import (
    ACTOR_EXIT_S,
    Actor,
    sigterm_as_exit,
    start_actor,
)
from bench.faults.service_kills import EPOCH, Up
from hercs.apps.deploy.certs import make_certs
from hercs.apps.launch.router import free_port
from hercs.run.rundir import RunDir

CUTS = ("", "both", "to-actors")


@dataclass(frozen=True)
class Setting:
    """One network fault, on every actor's link."""

    name: str
    loss: float = 0.0
    """Probability that a packet is dropped, each direction."""
    rate_mbit: float = 0.0
    """A token bucket of this rate on each direction (0: none)."""
    delay_ms: float = 0.0
    """A relay on the path holds each chunk this long, each direction ..."""
    jitter_ms: float = 0.0
    """... ± this much (uniform, order kept)."""
    cut: str = ""
    """"both": every packet dropped both ways for `cut_s` mid-run; "to-actors": only
    towards the actors (replies lost, requests arrive); "": no cut."""

    def __post_init__(self) -> None:
        if self.cut not in CUTS or not 0 <= self.loss < 1 or min(
                self.rate_mbit, self.delay_ms, self.jitter_ms) < 0:
            raise ValueError(f"setting {self.name}: got cut {self.cut!r} (one of {CUTS}), "
                             f"loss {self.loss} (in [0, 1)), rate {self.rate_mbit}, delay "
                             f"{self.delay_ms} ± {self.jitter_ms} (>= 0)")

    def describe(self, cut_s: float) -> str:
        parts = []
        if self.loss:
            parts.append(f"{self.loss:.0%} loss each way")
        if self.rate_mbit:
            parts.append(f"{self.rate_mbit:g} Mbit/s each way (tbf)")
        if self.delay_ms:
            jitter = f" ± {self.jitter_ms:g}" if self.jitter_ms else ""
            parts.append(f"{self.delay_ms:g}{jitter} ms each way (relay)")
        if self.cut:
            way = "both ways" if self.cut == "both" else "towards the actors only"
            parts.append(f"cut {cut_s:g} s {way}")
        return ", ".join(parts) or "nothing"


SETTINGS = {s.name: s for s in [
    Setting("baseline"),
    Setting("loss-2", loss=0.02),
    Setting("loss-10", loss=0.10),
    Setting("rate-10mbit", rate_mbit=10),
    Setting("latency-50", delay_ms=50, jitter_ms=10),
    Setting("latency-200", delay_ms=200),
    Setting("partition", cut="both"),
    Setting("partition-acks", cut="to-actors"),
]}
QUICK = Setting("loss-10+partition", loss=0.10, cut="both")
"""The quick run's one setting (tests/fault/test_network_faults.py): loss and a cut."""


@dataclass(frozen=True)
class Shape:
    """What each setting's run is: FetchReach HER-CS, `actors` remote actors."""

    epochs: int = 5
    cycles: int = 5
    actors: int = 2
    cut_at: int = 2
    """A cut starts right after this epoch's progress line."""
    cut_s: float = 60.0
    timeout_s: float = 600.0
    """Per wait (a progress line, the run's end)."""
    seed: int = 1


QUICK_SHAPE = Shape(epochs=5, cycles=2, actors=1, cut_at=1, cut_s=15.0)
"""The quick run: one actor, a 15 s cut (longer than the lease) after epoch 1 of 5. Five, not
three: the rate limiter lets the actor insert ahead of the learner, and by epoch 1's end it
had stored the episodes of three epochs' updates once, so a 3-epoch run ended in the cut
before any insert after the heal (a CI run failed so); five need episodes after the heal."""


def wait_for_learner_epochs(run_dir: Path, epochs: int, timeout_s: float, up: Up) -> None:
    """Until the learner has written `epochs` rows to metrics.csv (it writes each at its epoch
    end, before the evaluation); RuntimeError if `hercs up` ends first. The file has no event
    to await: it is read every 0.1 s."""
    deadline = time.monotonic() + timeout_s
    metrics = RunDir(run_dir).metrics
    while True:
        with contextlib.suppress(OSError):
            if len(metrics.read_text().strip().splitlines()) - 1 >= epochs:
                return
        if up.proc.poll() is not None:
            raise RuntimeError(f"hercs up ended (status {up.proc.returncode}) before the "
                               f"learner's epoch {epochs}")
        if time.monotonic() > deadline:
            raise TimeoutError(f"the learner did not end epoch {epochs} within {timeout_s:g} s")
        time.sleep(0.1)


def run_setting(setting: Setting, *, links: list[Host], certs: Path, root: Path,
                shape: Shape) -> NetResult:
    """One fresh run under `setting` on `links` (one actor each); faults and relays are
    removed however it ends."""
    run = f"net-{setting.name.replace('+', '-')}"
    run_dir = root / run
    root.mkdir(parents=True, exist_ok=True)
    port = free_port("0.0.0.0")  # every address: the router listens on each link
    load_before = os.getloadavg()[0]
    started = time.monotonic()
    relays: list[DelayRelay] = []
    actors: list[Actor] = []
    up: Up | None = None
    notes: list[str] = []
    healed_at: tuple[float, float] | None = None  # (monotonic, wall clock)
    next_epoch_s: float | None = None
    status, exits = -1, []
    try:
        endpoints = []
        for i, host in enumerate(links):
            if setting.loss:
                host.lose(setting.loss)
            if setting.rate_mbit:
                host.limit_rate(setting.rate_mbit)
            if setting.delay_ms:
                relay = DelayRelay(listen=(host.host_ip, 0), target=(host.host_ip, port),
                                   delay_s=setting.delay_ms / 1e3,
                                   jitter_s=setting.jitter_ms / 1e3,
                                   rng=np.random.default_rng([shape.seed, i]))
                relays.append(relay)
                endpoints.append(f"tls/{host.host_ip}:{relay.start()[1]}")
            else:
                endpoints.append(f"tls/{host.host_ip}:{port}")
        listen = [a for host in links for a in ("--listen", f"tls/{host.host_ip}:{port}")]
        up = Up([sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--method",
                 "her-cs", "--actors", "0", "--seed", str(shape.seed), "--run", run,
                 "--run-dir", str(root), "--tls-dir", str(certs), *listen,
                 "--set", f"training.epochs={shape.epochs}",
                 "--set", f"training.cycles_per_epoch={shape.cycles}",
                 "--set", "training.eval_episodes=5", "--set", "cluster.fgb_size=40",
                 # a cut of a minute in epochs of ~7 s is a stall by the launcher's measure
                 # (10 x the slowest epoch); the bench's own timeouts bound a stuck run
                 "--set", "launch.stall_factor=0"],
                root / f"{run}.out")
        actors = [start_actor(host, index=i + 1, endpoint=endpoint, run=run, certs=certs,
                              out=root)
                  for i, (host, endpoint) in enumerate(zip(links, endpoints, strict=True))]
        if setting.cut:
            both = setting.cut == "both"
            # After the learner's epoch `cut_at` (its metrics.csv row), not the launcher's
            # line for it: that waits for the evaluation, by which time a fast machine's
            # learner has used the episodes of later epochs and the run can end in the cut.
            wait_for_learner_epochs(run_dir, shape.cut_at, shape.timeout_s, up)
            for host in links:
                host.cut(both_ways=both)
            time.sleep(shape.cut_s)  # the fault's length: nothing to wait for but time
            for host in links:
                host.heal(both_ways=both)
            healed_at = (time.monotonic(), time.time())
            try:
                at = 0.0
                while at < healed_at[0]:  # a line stamped during the cut (updates ran ahead)
                    at, _ = up.wait_for(EPOCH, shape.timeout_s)
                next_epoch_s = at - healed_at[0]
            except (TimeoutError, RuntimeError) as exc:
                notes.append(f"no epoch after the heal: {exc}")
        status = up.finish(shape.timeout_s)
        for actor in actors:
            code, stopped = actor.stop(ACTOR_EXIT_S)
            exits.append(code)
            if stopped:
                notes.append(f"{actor.ident} did not stop by itself within {ACTOR_EXIT_S:g} s "
                             f"of the run's end; stopped with SIGTERM (exit {code})")
    except (TimeoutError, RuntimeError) as exc:  # the row says so; the next setting runs
        notes.append(f"the run did not finish: {exc}")
    finally:
        for relay in relays:
            relay.close()
        for host in links:
            host.clear()
        if up is not None and up.proc.poll() is None:
            up.kill_all()
        for actor in actors:
            if actor.proc.poll() is None:
                actor.proc.kill()
                actor.proc.wait()
    exits = exits or [-1 if a.proc.returncode is None else a.proc.returncode for a in actors]
    return measure(
        setting=setting.name, injected=setting.describe(shape.cut_s), run_dir=run_dir,
        actor_logs={actor.ident: actor.log for actor in actors},
        epochs_expected=shape.epochs, exit_status=status, actor_exits=exits,
        progress=up.seen if up is not None else [],
        healed_wall_s=None if healed_at is None else healed_at[1],
        next_epoch_after_heal_s=next_epoch_s, wall_s=time.monotonic() - started,
        load_before=load_before, load_after=os.getloadavg()[0], notes=notes)


def report(results: list[NetResult], *, command: str, shape: Shape, note: str,
           quick: bool) -> str:
    loads = [r.load_before for r in results] + [r.load_after for r in results]
    lines = [
        "# Network faults between hosts: one fault per run",
        "",
        f"`{command}` — {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, commit {git_commit()}, "
        f"{platform.node()} ({os.cpu_count()} cores; 1-min load average "
        f"{min(loads):.1f}–{max(loads):.1f} during the runs){' — QUICK MODE' if quick else ''}.",
        "",
        f"Each row is a fresh FetchReach HER-CS run of {shape.epochs} epochs × {shape.cycles} "
        f"cycles over mutual TLS: `hercs up --actors 0` on this host, {shape.actors} "
        "`hercs actor` each in its own network namespace behind a veth link carrying the "
        "fault (bench/faults/net_faults.py, bench/faults/netns.py). Cuts start once the "
        "learner has "
        f"written epoch {shape.cut_at}'s metrics row. Acked = distinct (actor, seq) the "
        "actors logged as acked; lost = "
        "those missing from the episode log at the end; stored twice = log records − "
        "distinct (actor, seq); dup acks = retries the replay answered as already stored. "
        "Lag: median of the epochs' p50 / largest p95 (cycles, metrics.csv). Inserts/s over "
        "the span of the log's insert times (a cut included); epoch = time between progress "
        "lines; heal → = from the end of a cut to the first insert / the next epoch line.",
        "",
    ]
    if note:
        lines += [f"Machine: {note}", ""]
    lines += [
        "| setting | injected | exit up / actors | epochs | acked | lost | stored twice | "
        "retries | dup acks | lag p50 / p95 | inserts/s | longest insert gap | "
        "epoch median / max | heal → insert / epoch | wall | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def s(value: float | None) -> str:
        return "–" if value is None else f"{value:g} s"

    for r in results:
        heal = (f"{s(r.first_insert_after_heal_s)} / {s(r.next_epoch_after_heal_s)}"
                if "cut" in r.injected else "–")
        lines.append(
            f"| {r.setting} | {r.injected} | {r.exit_status} / "
            f"{','.join(map(str, r.actor_exits))} | "
            f"{len(r.epochs_recorded)} ({r.epochs_expected}){'' if r.epochs_ok else ' ✗'} | "
            f"{r.acked} | {r.lost} | {r.stored_twice} | {r.retries} | {r.duplicate_acks} | "
            f"{r.lag_p50} / {r.lag_p95} | {r.inserts_per_s} | {s(r.longest_insert_gap_s)} | "
            f"{s(r.median_epoch_s)} / {s(r.max_epoch_s)} | {heal} | {r.wall_s} s | "
            f"{'ok' if r.ok else 'FAILED'} |")
    return table_with_notes(lines, ((r.setting, n) for r in results for n in r.notes))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--settings", nargs="+", choices=list(SETTINGS),
                        default=list(SETTINGS))
    parser.add_argument("--epochs", type=int, default=Shape.epochs)
    parser.add_argument("--cycles", type=int, default=Shape.cycles, help="cycles per epoch")
    parser.add_argument("--actors", type=int, default=Shape.actors,
                        help="actors, each in its own namespace")
    parser.add_argument("--cut-at", type=int, default=Shape.cut_at,
                        help="cut right after this epoch's progress line")
    parser.add_argument("--cut-s", type=float, default=Shape.cut_s,
                        help="how long a cut lasts, seconds (beyond Zenoh's 10 s lease the "
                        "sessions end and reopen)")
    parser.add_argument("--timeout", type=float, default=Shape.timeout_s,
                        help="per wait, seconds")
    parser.add_argument("--note", default="", help="a line about the machine for the report "
                        "(e.g. what else ran on it)")
    parser.add_argument("--out", type=Path, help="where net_faults.md and .json go (default "
                        "docs/results; a temp folder with --quick)")
    parser.add_argument("--keep", type=Path, help="put the run directories, logs and "
                        "certificates here and keep them (default: a temp folder, deleted)")
    parser.add_argument("--quick", action="store_true",
                        help=f"CI: one actor, {QUICK.name} (a 15 s cut after epoch 1 of 5)")
    args = parser.parse_args(argv)
    if (why := problem()) is not None:
        print(f"net_faults: cannot run here: {why}", file=sys.stderr)
        return 2
    settings = [SETTINGS[name] for name in args.settings]
    shape = Shape(epochs=args.epochs, cycles=args.cycles, actors=args.actors,
                  cut_at=min(args.cut_at, args.epochs - 1), cut_s=args.cut_s,
                  timeout_s=args.timeout)
    if args.quick:
        settings, shape = [QUICK], QUICK_SHAPE
    if shape.cut_at < 1 or shape.cut_s <= 0:
        parser.error(f"a cut needs --cut-at >= 1 with --epochs >= 2 and --cut-s > 0; got "
                     f"cut-at {shape.cut_at}, cut-s {shape.cut_s}")
    tmp = tempfile.TemporaryDirectory(prefix="hercs-net-faults-")
    out = args.out or (Path(tmp.name) if args.quick else REPO / "docs" / "results")
    work = args.keep or Path(tmp.name)
    root = work / "runs"
    results = []
    with sigterm_as_exit(), hosts(shape.actors) as links:
        certs = work / "certs"
        make_certs(certs, hosts=[host.host_ip for host in links])
        for setting in settings:
            print(f"net_faults: {setting.name} ({setting.describe(shape.cut_s)}) …", flush=True)
            result = run_setting(setting, links=links, certs=certs, root=root, shape=shape)
            print(f"net_faults: {setting.name}: {'ok' if result.ok else 'FAILED'} "
                  f"{asdict(result)}", flush=True)
            results.append(result)
    flags = "" if argv is None else " ".join(argv)
    command = f"python -m bench.faults.net_faults {flags or ' '.join(sys.argv[1:])}".strip()
    out.mkdir(parents=True, exist_ok=True)
    (out / "net_faults.md").write_text(report(results, command=command, shape=shape,
                                              note=args.note, quick=args.quick))
    (out / "net_faults.json").write_text(json.dumps(
        [{**asdict(r), "ok": r.ok, "stored_twice": r.stored_twice} for r in results],
        indent=2) + "\n")
    print(f"net_faults: wrote {out / 'net_faults.md'}")
    tmp.cleanup()
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
