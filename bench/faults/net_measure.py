"""What a network-fault run (bench.faults.net_faults) leaves behind, read back into one row: the
acks its actors logged, the episode log, `metrics.csv` and the launcher's progress lines.

Acked, lost and stored twice (docs/FAULTS.md, "Network faults"), retries, policy lag, inserts/s,
epoch time and, after a cut, the heal to the first insert.
"""

from __future__ import annotations

import re
import statistics
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.faults.service_kills import epoch_times, epochs_recorded
from hercs.proto import hercs_pb2 as pb
from hercs.run.metrics import read_rows
from hercs.run.rundir import RunDir
from hercs.run.runlog import TOPIC_EPISODES, read_messages

ACKED = re.compile(r"episode \((?P<actor>\S+), seq (?P<seq>\d+)\) acked(?P<dup> \(duplicate\))?$")
STOPPING = re.compile(
    r"stopping: (?P<episodes>\d+) episodes, (?P<acked>\d+) acked \((?P<duplicates>\d+) "
    r"duplicate[^)]*\), (?P<superseded>\d+) superseded, (?P<dropped>\d+) dropped, "
    r"(?P<unacked>\d+) given up unacked, (?P<retries>\d+) retries")


@dataclass
class NetResult:
    setting: str
    injected: str
    exit_status: int
    actor_exits: list[int]
    epochs_expected: int
    epochs_recorded: list[int]
    episodes: int
    """Episodes the actors collected (their stopping lines)."""
    acked: int
    """Distinct (actor_id, seq) the actors logged as acked."""
    lost: int
    stored_records: int
    stored_distinct: int
    duplicate_acks: int
    retries: int
    superseded: int
    unacked: int
    lag_p50: float | None
    lag_p95: float | None
    inserts_per_s: float | None
    longest_insert_gap_s: float | None
    median_epoch_s: float | None
    max_epoch_s: float | None
    wall_s: float
    load_before: float
    load_after: float
    first_insert_after_heal_s: float | None = None
    next_epoch_after_heal_s: float | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def stored_twice(self) -> int:
        return self.stored_records - self.stored_distinct

    @property
    def epochs_ok(self) -> bool:
        return self.epochs_recorded == list(range(1, self.epochs_expected + 1))

    @property
    def ok(self) -> bool:
        return (self.exit_status == 0 and all(c == 0 for c in self.actor_exits)
                and self.epochs_ok and self.acked > 0 and self.lost == 0
                and self.stored_twice == 0)


@dataclass
class ActorLog:
    acked: set[tuple[str, int]] = field(default_factory=set)
    duplicate_acks: int = 0
    counts: dict[str, int] | None = None
    """The stopping line's counts (None if the actor never wrote it)."""


def read_actor_log(path: Path) -> ActorLog:
    parsed = ActorLog()
    for line in path.read_text(errors="replace").splitlines():
        if m := ACKED.search(line):
            parsed.acked.add((m["actor"], int(m["seq"])))
            parsed.duplicate_acks += bool(m["dup"])
        elif m := STOPPING.search(line):
            parsed.counts = {k: int(v) for k, v in m.groupdict().items()}
    return parsed


def stored_episodes(run_dir: Path) -> tuple[list[tuple[str, int]], list[float]]:
    """Every episode record of the log as (actor_id, seq), and their insert times (s)."""
    pairs, times = [], []
    for message in read_messages(run_dir, [TOPIC_EPISODES]):
        episode = message.decode_as(pb.Episode)
        pairs.append((episode.actor_id, int(episode.seq)))
        times.append(message.publish_time_ns / 1e9)
    return pairs, times


def lag_summary(run_dir: Path) -> tuple[float | None, float | None]:
    """(median of the epochs' policy_lag_p50, largest policy_lag_p95) of metrics.csv."""
    def column(name: str) -> list[float]:
        values = [float(row.get(name) or "nan") for row in read_rows(RunDir(run_dir).metrics)]
        return [v for v in values if not np.isnan(v)]

    p50, p95 = column("policy_lag_p50"), column("policy_lag_p95")
    return (statistics.median(p50) if p50 else None, max(p95) if p95 else None)


def _rounded(value: float | None, digits: int = 2) -> float | None:
    return None if value is None else round(value, digits)


def measure(*, setting: str, injected: str, run_dir: Path, actor_logs: dict[str, Path],
            epochs_expected: int, exit_status: int, actor_exits: list[int],
            progress: list[tuple[float, str]], healed_wall_s: float | None,
            next_epoch_after_heal_s: float | None, wall_s: float, load_before: float,
            load_after: float, notes: list[str],
            killed: frozenset[str] = frozenset()) -> NetResult:
    """The row of one run: `actor_logs` by actor id, `progress` the launcher's timestamped
    lines, `healed_wall_s` the wall-clock time a cut ended (None: no cut). The logs named in
    `killed` are of actor processes SIGKILLed on purpose (bench.faults.chaos): they end without a
    stopping line, and only their ack lines count."""
    logs = {ident: read_actor_log(path) for ident, path in actor_logs.items()}
    acked = set().union(*(log.acked for log in logs.values()))
    pairs, times = stored_episodes(run_dir)
    stored = set(pairs)
    totals = {k: sum((log.counts or {}).get(k, 0) for log in logs.values())
              for k in ("episodes", "retries", "superseded", "unacked")}
    for ident, log in logs.items():
        if log.counts is None and ident not in killed:
            notes.append(f"{ident} wrote no stopping line (see {actor_logs[ident].name})")
        elif log.counts is not None and log.counts["acked"] != len(log.acked):
            notes.append(f"{ident}: {log.counts['acked']} acked by its count, "
                         f"{len(log.acked)} ack lines")
    times.sort()
    gaps = np.diff(times) if len(times) > 1 else np.zeros(0)
    durations = epoch_times(progress)
    first_after = None
    if healed_wall_s is not None:
        after = [t for t in times if t >= healed_wall_s]
        first_after = after[0] - healed_wall_s if after else None
    lag_p50, lag_p95 = lag_summary(run_dir)
    return NetResult(
        setting=setting, injected=injected, exit_status=exit_status, actor_exits=actor_exits,
        epochs_expected=epochs_expected, epochs_recorded=epochs_recorded(run_dir),
        episodes=totals["episodes"], acked=len(acked), lost=len(acked - stored),
        stored_records=len(pairs), stored_distinct=len(stored),
        duplicate_acks=sum(log.duplicate_acks for log in logs.values()),
        retries=totals["retries"], superseded=totals["superseded"], unacked=totals["unacked"],
        lag_p50=_rounded(lag_p50), lag_p95=_rounded(lag_p95),
        inserts_per_s=(_rounded((len(times) - 1) / (times[-1] - times[0]))
                       if len(times) > 1 and times[-1] > times[0] else None),
        longest_insert_gap_s=_rounded(float(gaps.max())) if gaps.size else None,
        median_epoch_s=_rounded(statistics.median(durations)) if durations else None,
        max_epoch_s=_rounded(max(durations)) if durations else None,
        wall_s=round(wall_s, 1), load_before=round(load_before, 2),
        load_after=round(load_after, 2), first_insert_after_heal_s=_rounded(first_after),
        next_epoch_after_heal_s=_rounded(next_epoch_after_heal_s), notes=notes)
