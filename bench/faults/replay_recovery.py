"""How long a killed replay takes to serve again, by the transitions its log holds.

    python -m bench.faults.replay_recovery [--quick] [--sizes 1e4,1e5,999950,1e6] [--repeats 3]

A real `hercs replay` started on a killed replay's log, and its constructor timed in parts.
Writes OUT/replay_recovery.{json,md} (`--out`); method and findings: docs/results/faults.md."""

from __future__ import annotations

import contextlib
import os
import queue
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from bench.common import REPO, git_commit, machine_identity, script_parser, write_report
from bench.faults.killed_replay_log import RUN, KilledRun, T, episode_msg, write_killed_run
from hercs.apps.launch.router import free_port
from hercs.net.transport import Transport
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.replay_service import builder, replay_recovery
from hercs.replay_service import replay_shell as replay_service
from hercs.replay_service.table import ReplayTable
from hercs.run.runlog import RecoveringLogWriter, latest_replay_state, segment_paths

SIZES = (10_000, 100_000, 999_950, 1_000_000)
"""10^6 twice: 19,999 episodes, killed one episode before the replay starts a new segment (the
live segment it must seal holds a whole segment, 5,000 episodes: the bounded log's worst
case), and 20,000, killed just after it started one (the best case)."""
QUICK_SIZES = (500, 2_500)
QUICK_BUFFER = 1_000
"""`--quick`: a 20-episode buffer (5-episode segments), so that the larger quick size is
recovered from a saved replay state and the buffer's episodes, as a long run is."""
QUICK_FGB = 20
"""`--quick`: `cluster.fgb_size`, so that the larger quick size logs cluster models too."""
SERVE_TIMEOUT_S = 900.0
PHASES = ("open", "read", "decode", "store", "cluster")
LOG_TIME = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ")

# -- a real `hercs replay` process ------------------------------------------------------

def _log_time(line: str) -> float | None:
    match = LOG_TIME.match(line)
    if match is None:
        return None
    return datetime.strptime(match.group(1), "%Y-%m-%d %H:%M:%S,%f").timestamp()


def _first_status(client: Transport, key: str, timeout_s: float) -> pb.ReplayStatus:
    """The next `ReplayStatus` the replay puts."""
    puts: queue.Queue[bytes] = queue.Queue()
    sub = client.subscribe(key, lambda _key, payload: puts.put(payload))
    try:
        return pb.ReplayStatus.FromString(puts.get(timeout=timeout_s))
    except queue.Empty:
        raise RuntimeError(f"no ReplayStatus within {timeout_s} s") from None
    finally:
        sub.close()


def time_process(run: KilledRun, client: Transport, log_path: Path) -> dict[str, Any]:
    """Start `hercs replay` on the killed run; the time until the retried insert is acked."""
    keys = RunKeys(RUN)
    last = episode_msg(run.config, run.episodes - 1).SerializeToString()
    with open(log_path, "wb") as log:
        started_wall, started = time.time(), time.monotonic()
        proc = subprocess.Popen(
            [sys.executable, "-m", "hercs.apps.cli", "replay", "--config",
             str(run.config_path), "--id", "replay"], cwd=REPO, stdout=log,
            stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            ack = pb.InsertAck.FromString(client.request(keys.insert, last,
                                                         timeout_s=SERVE_TIMEOUT_S))
            serving_s = time.monotonic() - started
            status = _first_status(client, keys.status, 30.0)
        finally:
            proc.send_signal(signal.SIGKILL)  # killed again, as the chaos soak kills it
            proc.wait()
    text = log_path.read_text(errors="replace")
    first_line = next((t for line in text.splitlines() if (t := _log_time(line)) is not None),
                      None)
    serving_line = next((t for line in text.splitlines()
                         if "replay serving run" in line and (t := _log_time(line))), None)
    return {
        "serving_s": serving_s,
        "first_log_line_s": None if first_line is None else first_line - started_wall,
        "recovered_s": None if serving_line is None else serving_line - started_wall,
        "ack_duplicate": ack.duplicate, "ack_episode_id": int(ack.episode_id),
        "status_inserts": int(status.inserts), "status_size_episodes": int(status.size_episodes),
        "status_cluster_model_version": int(status.cluster_model_version),
    }


# -- the replay's constructor in this process, timed in parts ------------------------------

class _StubTransport:
    """Takes the replay's declarations and does nothing with them."""

    def publisher(self, *args: Any, **kwargs: Any) -> _StubTransport:
        return self

    def put(self, payload: bytes) -> None:
        pass

    def serve(self, *args: Any, **kwargs: Any) -> None:
        pass

    serve_deferred = subscribe = serve


@dataclass
class _StubRuntime:
    keys: RunKeys
    transport: _StubTransport = field(default_factory=_StubTransport)


class _Clock:
    def __init__(self) -> None:
        self.spent: dict[str, float] = dict.fromkeys(PHASES, 0.0)

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.spent[name] += time.perf_counter() - start

    def timed(self, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            with self.phase(name):
                return fn(*args, **kwargs)
        return wrapper


def time_in_process(run: KilledRun) -> dict[str, Any]:
    """`ReplayService(...)` on the killed run, its recovery's parts timed (module docstring).
    The recovery's names (the table's in the builder that makes it) are wrapped for the call
    and put back after it."""
    clock = _Clock()
    named = {"RecoveringLogWriter": replay_recovery, "ReplayTable": builder,
             "msg_to_episode": replay_recovery, "_restore_cluster_model": replay_recovery}
    saved = {name: getattr(module, name) for name, module in named.items()}

    class TimedRecovered:
        def __init__(self, recovered: Any) -> None:
            self.recovered, self.replay_state = recovered, recovered.replay_state

        def __iter__(self) -> TimedRecovered:
            return self

        def __next__(self) -> tuple[int, pb.Episode]:
            with clock.phase("read"):
                return next(self.recovered)

    class TimedLog(RecoveringLogWriter):
        @classmethod
        def open(cls, *args: Any, **kwargs: Any) -> Any:
            with clock.phase("open"):
                log, recovered = saved["RecoveringLogWriter"].open(*args, **kwargs)
            return log, TimedRecovered(recovered)

    class TimedTable(ReplayTable):
        def recover(self, *args: Any, **kwargs: Any) -> list[tuple[int, int]]:
            start = time.perf_counter()
            before = clock.spent["read"] + clock.spent["decode"]
            try:
                return super().recover(*args, **kwargs)
            finally:  # what recover spent itself, not in the episodes it pulled
                clock.spent["store"] += (time.perf_counter() - start
                                         - (clock.spent["read"] + clock.spent["decode"] - before))

    patches = {"RecoveringLogWriter": TimedLog, "ReplayTable": TimedTable,
               "msg_to_episode": clock.timed("decode", saved["msg_to_episode"]),
               "_restore_cluster_model": clock.timed("cluster", saved["_restore_cluster_model"])}
    for name, value in patches.items():
        setattr(named[name], name, value)
    try:
        start = time.perf_counter()
        service = replay_service.ReplayService(parts=builder.ReplayBuilder(run.config),
                               runtime=_StubRuntime(RunKeys(RUN)),  # type: ignore[arg-type]
                               run_dir=run.run_dir)
        total = time.perf_counter() - start
    finally:
        for name, value in saved.items():
            setattr(named[name], name, value)
    store = service.table.store
    result = {"total_s": total, **{f"{name}_s": clock.spent[name] for name in PHASES},
              "inserted": store.num_inserted, "stored": store.size,
              "cluster_model_version": service.table.clusterer_state().model_version}
    service.close()
    return result


# -- the benchmark ----------------------------------------------------------------------------

def measure_size(root: Path, *, transitions: int, repeats: int, buffer: int | None,
                 extra: list[str], endpoint: str, client: Transport) -> dict[str, Any]:
    started = time.monotonic()
    run = write_killed_run(root, transitions=transitions, endpoint=endpoint, buffer=buffer,
                           extra=extra)
    write_s = time.monotonic() - started
    state = latest_replay_state(segment_paths(run.run_dir))
    process, in_process = [], []
    for i in range(repeats):
        run.reset()
        process.append(time_process(run, client, root / f"replay-{i}.log"))
        run.reset()
        in_process.append(time_in_process(run))
    capacity = run.config.capacity_episodes
    expected = {"inserted": run.episodes, "stored": min(run.episodes, capacity),
                "cluster_model_version": run.episodes // run.config.cluster.fgb_size}
    serving = [p["serving_s"] for p in process]
    totals = [p["total_s"] for p in in_process]
    phases = {name: statistics.median(p[f"{name}_s"] for p in in_process) for name in PHASES}
    return {
        "transitions": transitions, "episodes": run.episodes,
        "buffer_episodes": capacity, "write_s": write_s,
        "log_bytes": sum(run.files.values()), "log_segments": len(run.files),
        "replay_state": None if state is None else {
            "next_episode_id": int(state.next_episode_id),
            "first_held_id": int(state.first_held_id)},
        "expected": expected,
        "recovered_exactly": all(
            p["ack_duplicate"] and p["ack_episode_id"] == run.episodes - 1
            and p["status_inserts"] == expected["inserted"]
            and p["status_size_episodes"] == expected["stored"]
            and p["status_cluster_model_version"] == expected["cluster_model_version"]
            for p in process) and all(
            (p["inserted"], p["stored"], p["cluster_model_version"]) == tuple(expected.values())
            for p in in_process),
        "process": {"serving_s_median": statistics.median(serving),
                    "serving_s_max": max(serving), "runs": process},
        "in_process": {"total_s_median": statistics.median(totals),
                       "total_s_max": max(totals), "phases_s_median": phases,
                       "dominant": max(phases, key=lambda name: phases[name]),
                       "runs": in_process},
    }


def render(summary: dict[str, Any]) -> str:
    lines = ["# Replay recovery time after a kill, by stored transitions", "",
             f"`{summary['command']}` — git {summary['git']}; {summary['machine']['cpu']}; "
             f"{summary['repeats']} repeats per size (median / max).", "",
             "FetchPush (T = 50), HER-CS, buffer of "
             f"{summary['buffer_transitions']:,} transitions, the default bounded log; random "
             "episodes with their scenes and a cluster model every `cluster.fgb_size` "
             "episodes. *serving*: from the start of a `hercs replay` process to the ack of "
             "the retried insert; *recovered*: to its `replay serving run` line. The parts "
             "are the same constructor in process (module docstring of "
             "bench/faults/replay_recovery.py).", "",
             "| transitions | episodes | log MB | starts from a state | serving s | recovered s "
             "| in process s | open | read | decode | store | cluster | dominant | exact |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in summary["sizes"]:
        proc, inp = row["process"], row["in_process"]
        recovered = [r["recovered_s"] for r in proc["runs"] if r["recovered_s"] is not None]
        state = row["replay_state"]
        ph = inp["phases_s_median"]
        lines.append(
            f"| {row['transitions']:,} | {row['episodes']:,} | {row['log_bytes'] / 1e6:.1f} | "
            + (f"{state['next_episode_id']:,} (buffer from {state['first_held_id']:,})"
               if state else "no") + " | "
            f"{proc['serving_s_median']:.2f} / {proc['serving_s_max']:.2f} | "
            + (f"{statistics.median(recovered):.2f}" if recovered else "?") + " | "
            f"{inp['total_s_median']:.2f} / {inp['total_s_max']:.2f} | "
            + " | ".join(f"{ph[name]:.2f}" for name in PHASES)
            + f" | {inp['dominant']} | {'yes' if row['recovered_exactly'] else 'NO'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = script_parser("bench.faults.replay_recovery", __doc__)
    parser.add_argument("--quick", action="store_true",
                        help=f"sizes {QUICK_SIZES} with a {QUICK_BUFFER}-transition buffer, "
                             "2 repeats (CI)")
    parser.add_argument("--sizes", help="stored transitions, comma-separated (default "
                                        "1e4,1e5,999950,1e6)")
    parser.add_argument("--repeats", type=int, help="recoveries per size (default 3)")
    parser.add_argument("--buffer", type=float, help="replay.buffer_transitions (default: "
                                                     "the config's)")
    parser.add_argument("--out", type=Path, help="folder for replay_recovery.{json,md} "
                                                 "(default docs/results; none with --quick)")
    args = parser.parse_args(argv)
    sizes = ([int(float(s)) for s in args.sizes.split(",")] if args.sizes
             else list(QUICK_SIZES if args.quick else SIZES))
    repeats = args.repeats or (2 if args.quick else 3)
    buffer = (int(args.buffer) if args.buffer else QUICK_BUFFER if args.quick else None)
    extra = [f"cluster.fgb_size={QUICK_FGB}"] if args.quick else []
    out = args.out if args.out is not None or args.quick else REPO / "docs/results"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    flags = [("--quick", args.quick), (f"--sizes {args.sizes}", args.sizes),
             (f"--repeats {args.repeats}", args.repeats), (f"--buffer {args.buffer}", args.buffer)]
    command = "python -m bench.faults.replay_recovery" + "".join(f" {f}" for f, on in flags if on)
    rows = []
    router = Transport.open(mode="router", listen=[endpoint])
    client = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=10.0,
                            rediscover_s=0)
    try:
        for transitions in sizes:
            with tempfile.TemporaryDirectory(dir=REPO, prefix=".replay_recovery-") as tmp:
                row = measure_size(Path(tmp), transitions=transitions, repeats=repeats,
                                   buffer=buffer, extra=extra, endpoint=endpoint,
                                   client=client)
            rows.append(row)
            print(f"{transitions:,} transitions: serving {row['process']['serving_s_median']:.2f}"
                  f" s median, {row['process']['serving_s_max']:.2f} s max; in process "
                  f"{row['in_process']['phases_s_median']}", flush=True)
    finally:
        client.close()
        router.close()
    summary = {"command": command, "git": git_commit(), "machine": machine_identity(),
               "repeats": repeats,
               "buffer_transitions": rows[0]["buffer_episodes"] * T if rows else 0,
               "sizes": rows}
    text = render(summary)
    print(text)
    write_report(out, "replay_recovery", summary, text)
    return 0 if all(row["recovered_exactly"] for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
