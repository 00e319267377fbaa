"""Throughput of the running system against its physical limits, measured side by side.

    python -m bench.throughput                 # full mode, ~5-10 min on 2 cores → docs/results/
    python -m bench.throughput --quick         # CI mode: tiny sizes, well under a minute

One invocation measures every figure below and writes `throughput.json` (every figure, the
raw measurements behind it, the machine, commit, date and command) and `throughput.md` (a
table: figure, ours, reference, ratio, target, verdict) to `--out`, and prints the markdown.
Targets are reported, never asserted: a noisy machine moves absolute numbers, so each figure
of the system ("ours") is paired with a reference measured in the same run, for the two
throughput pairs in short alternating slices (the system's process is paused with SIGSTOP
while the reference runs), and the ratio is what the target is about.

Figures (the system is real: an embedded Zenoh router on a free loopback port, and
`python -m apps.cli <role>` child processes connected to it):

1. **Env steps/s.** ours: one `hercs actor` (policy inference, exploration noise, acked
   inserts over Zenoh) counted at the replay — acked episodes × T per second from the
   `replay/inserted` headers. reference: raw FetchPush-v4 stepping with uniform random actions
   in this process. The two alternate in short slices (full mode: 12 actor slices of 2.5 s,
   each between two raw ones), so drifts of the background load hit both sides alike.
   Target ratio ≥ 0.9. Also per CPU-second of the actor process and of the stepping thread:
   the rates each would reach on a core of its own, free of the machine's load.
2. **Learner updates/s.** ours: the `hercs learner` process pulling 40×256 batches from the
   replay over Zenoh (its prefetcher overlaps sampling and transport with updates), counted
   from its `weights` broadcasts (one per cycle of `minibatches_per_cycle` updates).
   reference: the same `LearnerLoop.step` (DDPG updates, Polyak update) in this process, one
   torch thread as the service, on batches sampled beforehand from a local `ReplayCore`
   (sampling is outside the timed loop: the service's prefetch is meant to hide it);
   alternating slices as above (full mode: 8 of 4 s). Target ratio ≥ 0.95. Also per
   CPU-second of the learner process (all its threads) and of the updating thread.
3. **Insert throughput** with 1, 2, 4, 8, 16 concurrent synthetic actors (quick: 1, 2): each
   has its own Zenoh client session and one insert in flight, as `actors.inserter` delivers;
   episodes are pre-generated random Push episodes (`hercs.episode.random_episode`). ratio =
   speed-up over one actor; target ≥ 1,000 acked episodes/s from 8 actors. At the end of the
   run the largest levels (8, 16; quick: 2) are measured again into a replay of its own with
   `replay.log_scene=false` (every episode logged, no Foxglove scene drawn), against the
   same level with scenes: what drawing the scenes costs the replay's one core.
4. **Sample latency** of a SampleRequest of 40 minibatches × 256 on a full buffer (1e6
   transitions = 20,000 Push episodes; quick: 500 episodes), for each sampler (`her`, `her-cs`,
   `her-ebp`, `her-ebp-cs`; quick: the first two): time from
   sending the request to holding the reply bytes, at a client of the router (the learner's
   path), decode excluded; per request and per minibatch (÷ 40). reference: `ReplayCore.sample`
   of the same size in this process on a store of the same size. Target p99 ≤ 1 ms per
   minibatch. The `her` replay is the one filled over Zenoh; the `her-cs` replay is the same
   run restarted with `run.method=her-cs`, refilled from its episode log (the replay's own
   crash recovery), and given a k=8 `ClusterModel` published on `cluster/model` as the
   clusterer would (its adoption is checked through `ReplayStatus.cluster_model_version`).
5. **Replay memory.** ours: VmRSS − RssShmem of the replay process holding 1e6 transitions,
   after serving the `her` sample requests, minus the same when it had just started (empty
   store: `np.zeros` commits no pages). RssShmem is Zenoh's shared-memory pools of the local
   senders, mapped by the replay (see `own_rss_mib`). reference: the bytes of the store's
   arrays at that size (per episode: obs, ag, g, actions and the per-episode metadata
   columns, the object column counted as pointers). Target ratio ≤ 1.5. The total VmRSS (no
   subtraction) is reported too.

The replay runs with `replay.free_run=true` throughout: there is no learner while the actor
is measured and no actor while the learner is, so the sample-to-insert rate limiter would
otherwise hold one side and the phase would measure the limiter, not the path.

Every child runs in its own process group and gets SIGKILL if this process dies
(PR_SET_PDEATHSIG); each phase stops its children with SIGTERM, then SIGKILL after a grace
period, in `finally` blocks.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import ctypes
import dataclasses
import json
import math
import os
import platform
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any, Literal

import numpy as np

# ----------------------------------------------------------------------------- pure helpers
# Everything in this section is free of processes, Zenoh and clocks (tests check exact values).

MEETS = "meets target"
BELOW = "below target"
NO_TARGET = "no target"

TargetKind = Literal["ratio_at_least", "ratio_at_most", "ours_at_most", "ours_at_least"]


class BenchError(RuntimeError):
    """A phase could not measure what it should (a child died, a wait timed out)."""


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile (0 ≤ q ≤ 100), linear between the two closest ranks.

    Same definition as numpy's default (`method="linear"`): sorted x, position
    p = (n − 1)·q/100, result x[⌊p⌋] + (p − ⌊p⌋)·(x[⌊p⌋+1] − x[⌊p⌋]).
    """
    if not values:
        raise ValueError("percentile: got no values")
    if not 0.0 <= q <= 100.0:
        raise ValueError(f"percentile: got q={q}, must lie in [0, 100]")
    xs = sorted(float(v) for v in values)
    pos = (len(xs) - 1) * q / 100.0
    lo = math.floor(pos)
    hi = min(lo + 1, len(xs) - 1)
    return xs[lo] + (pos - lo) * (xs[hi] - xs[lo])


def pooled_rate(slices: Sequence[Sequence[tuple[float, float]]]) -> float:
    """Rate over several time slices from (arrival time, cumulative count) samples.

    Σ (count_last − count_first) / Σ (t_last − t_first) over the slices with at least two
    samples: each slice contributes only whole intervals between its own arrivals, so the
    pauses between slices (and partial intervals at their edges) are never counted.
    """
    amount = span = 0.0
    for samples in slices:
        if len(samples) < 2:
            continue
        ordered = sorted(samples)
        amount += ordered[-1][1] - ordered[0][1]
        span += ordered[-1][0] - ordered[0][0]
    if span <= 0:
        raise BenchError(f"pooled_rate: no slice of {len(slices)} holds two distinct arrivals")
    return amount / span


def work_in_windows(samples: Sequence[tuple[float, float]],
                    windows: Sequence[tuple[float, float]]) -> float:
    """Work done inside time windows, from (time, cumulative count) samples.

    Per window (start, end]: count at the last sample at or before `end` minus count at the
    last sample at or before `start` (0 before the first sample: counts start at 0). Unlike
    `pooled_rate` it counts work that straddles a window's edges as falling in the window it
    finished in, which evens out over many windows; it pairs with CPU time measured over the
    same windows.
    """
    ordered = sorted(samples)
    times = [t for t, _ in ordered]

    def count_at(t: float) -> float:
        i = bisect.bisect_right(times, t)
        return ordered[i - 1][1] if i else 0.0

    return sum(count_at(end) - count_at(start) for start, end in windows)


@dataclasses.dataclass(frozen=True)
class Target:
    """What a figure must achieve: a bound on the ratio ours/reference, or on ours itself."""

    kind: TargetKind
    value: float

    def met(self, *, ours: float, ratio: float) -> bool:
        if self.kind == "ratio_at_least":
            return ratio >= self.value
        if self.kind == "ratio_at_most":
            return ratio <= self.value
        if self.kind == "ours_at_least":
            return ours >= self.value
        return ours <= self.value

    def describe(self, unit: str) -> str:
        """E.g. `ratio ≥ 0.9`, `ratio ≤ 1.5`, `≤ 5 ms`."""
        if self.kind == "ratio_at_least":
            return f"ratio ≥ {self.value:g}"
        if self.kind == "ratio_at_most":
            return f"ratio ≤ {self.value:g}"
        if self.kind == "ours_at_least":
            return f"≥ {format_value(self.value, unit)}"
        return f"≤ {format_value(self.value, unit)}"


def verdict(target: Target | None, *, ours: float, ratio: float) -> str:
    """`meets target`, `below target` (the bound is missed, whichever way it points), or
    `no target`."""
    if target is None:
        return NO_TARGET
    return MEETS if target.met(ours=ours, ratio=ratio) else BELOW


@dataclasses.dataclass(frozen=True)
class Figure:
    """One row of the report: ours against its reference, with ratio = ours / reference."""

    key: str
    """Stable identifier (JSON key, test selector)."""
    name: str
    """Row label in the table."""
    unit: str
    ours: float
    reference: float
    ours_what: str
    """What `ours` measured."""
    reference_what: str
    """What `reference` measured."""
    target: Target | None = None

    @property
    def ratio(self) -> float:
        return self.ours / self.reference

    @property
    def verdict(self) -> str:
        return verdict(self.target, ours=self.ours, ratio=self.ratio)

    def to_dict(self) -> dict[str, Any]:
        target = None if self.target is None else {
            "kind": self.target.kind, "value": self.target.value,
            "text": self.target.describe(self.unit)}
        return {"key": self.key, "name": self.name, "unit": self.unit, "ours": self.ours,
                "reference": self.reference, "ratio": self.ratio, "target": target,
                "verdict": self.verdict, "ours_what": self.ours_what,
                "reference_what": self.reference_what}


def format_value(value: float, unit: str) -> str:
    """A number with its unit, to a precision that suits its size (3 significant digits
    below 100, whole numbers with thousands separators above)."""
    if abs(value) >= 100:
        text = f"{value:,.0f}"
    elif abs(value) >= 10:
        text = f"{value:.1f}"
    elif abs(value) >= 1:
        text = f"{value:.2f}"
    else:
        text = f"{value:.3g}"
    return f"{text} {unit}" if unit else text


def format_ratio(ratio: float) -> str:
    return f"{ratio:.2f}×" if ratio < 100 else f"{ratio:,.0f}×"


TABLE_HEADER = ("figure", "ours", "reference", "ratio", "target", "verdict")


def markdown_table(figures: Sequence[dict[str, Any]]) -> str:
    """The report table from `Figure.to_dict()` rows (so it can be rebuilt from the JSON)."""
    lines = ["| " + " | ".join(TABLE_HEADER) + " |",
             "|" + "|".join(["---"] + ["---:"] * 3 + ["---"] * 2) + "|"]
    for f in figures:
        target = f["target"]["text"] if f["target"] else "–"
        lines.append(f"| {f['name']} | {format_value(f['ours'], f['unit'])} | "
                     f"{format_value(f['reference'], f['unit'])} | {format_ratio(f['ratio'])} | "
                     f"{target} | {f['verdict']} |")
    return "\n".join(lines) + "\n"


def render_markdown(report: dict[str, Any]) -> str:
    """The whole `throughput.md` from the report dict written to `throughput.json`."""
    m = report["machine"]
    lines = [
        "# Throughput", "",
        f"Mode **{report['mode']}**, {report['date']}, commit `{report['git_commit']}`, "
        f"{report['total_wall_s']:.0f} s.", "",
        f"Machine: {m['cpu_count']} × {m['cpu_model']}, {m['ram_gib']:.0f} GiB RAM, "
        f"Python {m['python']}, torch {m['versions'].get('torch')}, mujoco "
        f"{m['versions'].get('mujoco')}, zenoh {m['versions'].get('eclipse-zenoh')}; load "
        f"average {m['load_avg_start'][0]:.1f} at the start, {m['load_avg_end'][0]:.1f} at "
        "the end.", "",
        f"Command: `{report['command']}`", "",
    ]
    if report["mode"] == "quick":
        lines += ["Quick mode (CI): tiny sizes and windows, so the verdicts mean nothing; it "
                  "checks that every measurement still runs.", ""]
    lines += [markdown_table(report["figures"]).rstrip("\n"), "",
              "## What each row compares", ""]
    # Rows measured the same way (e.g. p50 and p99 of one sample) share one line.
    groups: dict[tuple[str, str], list[str]] = {}
    for f in report["figures"]:
        groups.setdefault((f["ours_what"], f["reference_what"]), []).append(f["name"])
    lines += [f"- {', '.join(f'**{n}**' for n in names)} — ours: {ours}; reference: {ref}."
              for (ours, ref), names in groups.items()]
    lines += ["", "## How", ""] + [f"- {note}" for note in report["notes"]]
    return "\n".join(lines) + "\n"


def parse_proc_status_kib(text: str, field: str) -> int:
    """A `kB` field (e.g. VmRSS) of a /proc/<pid>/status text, in KiB."""
    for line in text.splitlines():
        name, _, rest = line.partition(":")
        if name == field:
            value, _, unit = rest.strip().partition(" ")
            if unit.strip() != "kB":
                raise ValueError(f"/proc status {field}: unexpected unit in {line!r}")
            return int(value)
    raise ValueError(f"/proc status: no field {field!r}")


NO_SCENE = "her-no-scene"
"""Config key of the replay that draws no scenes (inserts phase without scenes)."""


def figure_keys(*, actor_counts: Sequence[int], methods: Sequence[str],
                no_scene_counts: Sequence[int] = ()) -> list[str]:
    """Every figure key a run with these insert levels and sample methods reports, in order."""
    keys = ["env_steps_per_s", "env_steps_per_cpu_s", "learner_updates_per_s",
            "learner_updates_per_cpu_s", "learner_roofline_fp32", "learner_roofline_bf16"]
    keys += [f"inserts_per_s_{n}_actors" for n in actor_counts]
    for method in methods:
        keys += [f"sample_{stat}_{per}_{method}" for per in ("minibatch", "request")
                 for stat in ("p50", "p99")]
    keys += ["replay_rss_growth", "replay_rss_total"]
    keys += [f"inserts_per_s_{n}_actors_no_scene" for n in no_scene_counts]
    return keys


# ----------------------------------------------------------------------------- sizes

@dataclasses.dataclass(frozen=True)
class Plan:
    """Sizes and time windows of one invocation."""

    mode: str
    env_rounds: int
    """Rounds of (raw env slice, actor slice); one more raw slice closes the last round."""
    env_slice_s: float
    actor_warmup_episodes: int
    """Acked episodes the actor produces before the first round (start-up, first reset)."""
    learner_rounds: int
    """Rounds of (in-process slice, learner slice); one more in-process slice closes them."""
    learner_slice_s: float
    """At most 4 s: the learner is paused (SIGSTOP) that long, within Zenoh's 5 s limit on a
    blocked link and its 10 s lease."""
    learner_warmup_cycles: int
    """Weights versions the learner broadcasts before the first round (start-up, first batch)."""
    minibatches_per_cycle: int
    learner_min_episodes: int
    """Episodes the replay holds (topped up with synthetic ones) before the learner starts."""
    insert_actor_counts: tuple[int, ...]
    insert_warmup_s: float
    insert_window_s: float
    insert_no_scene_counts: tuple[int, ...]
    """Insert levels measured again with `replay.log_scene=false` (a replay of its own)."""
    buffer_transitions: int
    sample_requests: int
    sample_warmup_requests: int
    sample_minibatches: int = 40
    sample_batch_size: int = 256
    methods: tuple[str, ...] = ("her", "her-cs", "her-ebp", "her-ebp-cs")
    actor_envs: int = 4
    """`actor.envs_per_process` of the measured actor."""
    roofline_updates: int = 400
    """Timed updates per precision against the GEMM limit (bench/learner.py)."""
    roofline_gemms: int = 2000
    """Timed 256×256×256 products per precision for the core's GEMM rate."""


FULL = Plan(mode="full", env_rounds=12, env_slice_s=2.5, actor_warmup_episodes=3,
            learner_rounds=8, learner_slice_s=4.0, learner_warmup_cycles=2,
            minibatches_per_cycle=40, learner_min_episodes=200,
            insert_actor_counts=(1, 2, 4, 8, 16), insert_warmup_s=1.0, insert_window_s=10.0,
            insert_no_scene_counts=(8, 16), buffer_transitions=1_000_000,
            sample_requests=200, sample_warmup_requests=5)
QUICK = Plan(mode="quick", env_rounds=2, env_slice_s=1.0, actor_warmup_episodes=1,
             learner_rounds=2, learner_slice_s=1.5, learner_warmup_cycles=1,
             minibatches_per_cycle=10, learner_min_episodes=20,
             insert_actor_counts=(1, 2), insert_warmup_s=0.3, insert_window_s=1.5,
             insert_no_scene_counts=(2,), buffer_transitions=25_000, sample_requests=20,
             sample_warmup_requests=2,
             methods=("her", "her-cs"), actor_envs=2, roofline_updates=10,
             roofline_gemms=200)

# ----------------------------------------------------------------------------- the system

import torch

from apps.router import open_router
from bench.common import cpu_info, git_commit
from bench.learner import gemm_rate, make_batch, update_flops, update_rate
from hercs.clustering import ClusterModel
from hercs.codec import cluster_model_to_msg, episode_to_msg
from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.envs import make_env
from hercs.episode import EpisodeData, random_episode
from hercs.seeding import generator, int_seed
from hercs.tasks import TaskSpec
from hercs.transport import Transport
from hercs.validation import parse_message
from learner.ddpg import DDPGLearner
from learner.loop import LearnerLoop, SampleBatch
from proto import SCHEMA_VERSION
from proto import hercs_pb2 as pb
from proto.keys import RunKeys
from replay_service.core import ReplayCore
from replay_service.store import EpisodeStore

REPO = Path(__file__).resolve().parents[1]

RUN = "throughput"
SEED = 1
ACTOR_ID = "bench-actor"
K_CLUSTERS = 8
STORE_COLUMNS = ("obs", "ag", "g", "actions", "episode_id", "actor_id", "seq", "success",
                 "final_ag", "energy", "cluster", "policy_version")
"""The store's per-episode arrays (public views of `EpisodeStore`), for the raw byte count."""
EPISODE_POOL = 256
"""Distinct synthetic episodes cycled through by the synthetic actors."""
READY_TIMEOUT_S = 180.0
"""Longest wait for a child to come up (imports on a loaded 2-core machine are slow) or for
the replay to recover its log."""
REQUEST_TIMEOUT_S = 60.0
STOP_GRACE_S = 15.0
MAX_REPLY_BYTES = 1 << 30
MEMORY_FIELDS = ("VmRSS", "RssAnon", "RssFile", "RssShmem", "VmHWM")
"""VmRSS = RssAnon (heap, numpy arrays) + RssFile (mapped code and files) + RssShmem (shared
memory: here Zenoh's pools, see `own_rss_mib`); VmHWM = peak VmRSS."""
_PR_SET_PDEATHSIG = 1


def say(text: str) -> None:
    """Progress on stderr (stdout carries the markdown report)."""
    print(f"[throughput {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def free_endpoint() -> str:
    """A loopback TCP endpoint nothing listens on; never 7447 (other runs use it)."""
    while True:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.bind(("127.0.0.1", 0))
            port = int(sock.getsockname()[1])
        if port != 7447:
            return f"tcp/127.0.0.1:{port}"


def _pdeathsig_preexec() -> Callable[[], None] | None:
    """A `preexec_fn` giving the child SIGKILL when this process dies (Linux only); children
    are started from the main thread, whose exit is what fires it."""
    if not sys.platform.startswith("linux"):
        return None
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong,
                      ctypes.c_ulong]
    sigkill, parent = int(signal.SIGKILL), os.getpid()

    def preexec() -> None:
        prctl(_PR_SET_PDEATHSIG, sigkill, 0, 0, 0)
        if os.getppid() != parent:
            os._exit(1)

    return preexec


class Child:
    """`python -m apps.cli <role> --config FILE --id ID` in its own process group."""

    def __init__(self, *, role: str, ident: str, config_path: Path, log_dir: Path) -> None:
        self.role = role
        self.ident = ident
        self.log_path = log_dir / f"{ident}.log"
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        with self.log_path.open("ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "apps.cli", role, "--config", str(config_path),
                 "--id", ident],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env,
                cwd=REPO, close_fds=True, process_group=0, preexec_fn=_pdeathsig_preexec())

    @property
    def pid(self) -> int:
        return self.proc.pid

    def check_alive(self) -> None:
        code = self.proc.poll()
        if code is not None:
            raise BenchError(f"{self.role} {self.ident} exited with {code}; end of its log "
                             f"{self.log_path}:\n{self.log_tail()}")

    def memory_mib(self) -> dict[str, float]:
        """`MEMORY_FIELDS` of /proc/<pid>/status, in MiB."""
        self.check_alive()
        text = Path(f"/proc/{self.pid}/status").read_text()
        return {name: parse_proc_status_kib(text, name) / 1024 for name in MEMORY_FIELDS}

    def cpu_seconds(self) -> float:
        """User + system CPU time the process has used so far (its threads included)."""
        self.check_alive()
        fields = Path(f"/proc/{self.pid}/stat").read_text().rpartition(")")[2].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def pause(self) -> None:
        """SIGSTOP the process group: it uses no CPU until `resume`."""
        self.check_alive()
        self._signal_group(signal.SIGSTOP)

    def resume(self) -> None:
        self._signal_group(signal.SIGCONT)

    def log_tail(self, lines: int = 25) -> str:
        with contextlib.suppress(OSError):
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        return "(no log)"

    def _signal_group(self, sig: int) -> None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, sig)

    def stop(self, grace_s: float = STOP_GRACE_S) -> int:
        """SIGTERM to the group, wait `grace_s`, then SIGKILL; returns the exit code."""
        if self.proc.poll() is None:
            self._signal_group(signal.SIGTERM)
            self._signal_group(signal.SIGCONT)  # a paused child handles SIGTERM only now
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                say(f"{self.role} {self.ident} ignored SIGTERM for {grace_s:g} s; killing it")
        self._signal_group(signal.SIGKILL)  # the child, if it hung, and anything it forked
        self.proc.wait()
        return int(self.proc.returncode)


class Latest:
    """The newest value of a stream, with a wait for a condition on it."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._value: Any = None

    def set(self, value: Any) -> None:
        with self._cond:
            self._value = value
            self._cond.notify_all()

    def clear(self) -> None:
        self.set(None)

    def wait_for(self, pred: Callable[[Any], bool], timeout_s: float) -> Any:
        """The first value satisfying `pred` (None never does), or None after `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._value is None or not pred(self._value):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(min(remaining, 0.5))
            return self._value


class Arrivals:
    """(arrival time, value) of every sample of a stream, appended from a Zenoh thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: list[tuple[float, Any]] = []

    def add(self, value: Any) -> None:
        now = time.monotonic()
        with self._lock:
            self._items.append((now, value))

    def snapshot(self) -> list[tuple[float, Any]]:
        with self._lock:
            return list(self._items)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()

    def wait_count(self, pred: Callable[[Any], bool], count: int, *, timeout_s: float,
                   alive: Child) -> list[tuple[float, Any]]:
        """Wait until `count` items satisfy `pred`; BenchError (with `alive`'s log) if not."""
        deadline = time.monotonic() + timeout_s
        while True:
            items = [(t, v) for t, v in self.snapshot() if pred(v)]
            if len(items) >= count:
                return items
            alive.check_alive()
            if time.monotonic() > deadline:
                raise BenchError(f"only {len(items)} of {count} expected messages within "
                                 f"{timeout_s:g} s; end of {alive.log_path}:\n{alive.log_tail()}")
            time.sleep(0.05)


class SyntheticActor:
    """Inserts pre-generated episodes one at a time, each awaited until acked (as
    `actors.inserter` delivers), over its own Zenoh client session; acks are timestamped.

    The session stays open across `start`/`stop` runs: every new local session that sends
    large messages gives the replay one more Zenoh shared-memory pool to map (see
    `own_rss_mib`), so the benchmark opens as few as it can.
    """

    def __init__(self, *, name: str, endpoint: str, pool: Sequence[EpisodeData],
                 task: str) -> None:
        self.name = name
        self._pool = pool
        self._task = task
        self._keys = RunKeys(RUN)
        self.transport = Transport.open(mode="client", connect=[endpoint],
                                        connect_timeout_s=30.0)
        self.acks: list[tuple[float, int, float]] = []
        """(ack time, episode id, request latency s) of every run, appended by the sender."""
        self.error: BaseException | None = None
        self._seq = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"synthetic-{self.name}",
                                        daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                seq = self._seq
                episode = dataclasses.replace(self._pool[seq % len(self._pool)],
                                              actor_id=self.name, seq=seq)
                payload = episode_to_msg(episode, run=RUN, task=self._task).SerializeToString()
                sent = time.monotonic()
                raw = self.transport.request(self._keys.insert, payload,
                                             timeout_s=REQUEST_TIMEOUT_S)
                acked = time.monotonic()
                ack = parse_message(raw, pb.InsertAck, max_bytes=1 << 16)
                if ack.seq != seq or ack.duplicate:
                    raise BenchError(f"{self.name}: ack for seq {ack.seq} "
                                     f"(duplicate={ack.duplicate}), expected a new seq {seq}")
                self.acks.append((acked, int(ack.episode_id), acked - sent))
                self._seq += 1
        except BaseException as exc:  # reported by `SyntheticFleet.running`
            if not self._stop.is_set():
                self.error = exc

    def stop(self) -> None:
        """Stop after the insert in flight is acked."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(REQUEST_TIMEOUT_S + 5.0)

    def close(self) -> None:
        self.stop()
        self.transport.close()


class SyntheticFleet:
    """`size` synthetic actors whose sessions are opened once; `running(n)` runs the first n."""

    def __init__(self, *, size: int, endpoint: str, pool: Sequence[EpisodeData],
                 task: str) -> None:
        self.actors: list[SyntheticActor] = []
        try:
            for i in range(size):
                self.actors.append(SyntheticActor(name=f"synthetic-{i}", endpoint=endpoint,
                                                  pool=pool, task=task))
        except BaseException:
            self.close()
            raise

    @contextlib.contextmanager
    def running(self, n: int) -> Iterator[list[SyntheticActor]]:
        """The first `n` actors insert until the block exits; a failed actor raises then."""
        actors = self.actors[:n]
        try:
            for actor in actors:
                actor.start()
            yield actors
        finally:
            for actor in actors:
                actor.stop()
        errors = [a.error for a in actors if a.error is not None]
        if errors:
            raise BenchError(f"a synthetic actor failed: {errors[0]!r}")

    def acks_between(self, start: float, end: float) -> list[tuple[float, int, float]]:
        return [a for actor in self.actors for a in actor.acks if start <= a[0] < end]

    def newest_episode_id(self) -> int:
        return max((a.acks[-1][1] for a in self.actors if a.acks), default=-1)

    def close(self) -> None:
        for actor in self.actors:
            actor.close()


def episode_pool(spec: TaskSpec, size: int) -> list[EpisodeData]:
    rng = generator(SEED, "bench", "episodes")
    return [random_episode(spec, rng, actor_id="pool", seq=i) for i in range(size)]


def store_bytes_per_episode(spec: TaskSpec) -> int:
    """Bytes of one episode in the store's arrays (`STORE_COLUMNS`; the object column of actor
    ids counts its 8-byte pointers, not the strings)."""
    store = EpisodeStore(capacity_episodes=1, spec=spec)
    store.insert(random_episode(spec, generator(SEED, "bench", "bytes")))
    return int(sum(getattr(store, name).nbytes for name in STORE_COLUMNS))


def own_rss_mib(memory: dict[str, float]) -> float:
    """VmRSS without RssShmem: the pages this process owns.

    Zenoh 1.x enables its shared-memory transport optimisation by default: every local session
    that sends messages above 3 KiB (Episodes, Batches) allocates a 16 MiB pool, and a receiver
    maps the senders' pools, so the replay's VmRSS grew by up to 16 MiB per local peer that
    ever sent it a large message — pages owned and counted by the sender too, independent of
    what the replay stores. Our sessions now turn it off (hercs/transport.py), so RssShmem
    should be ~0; it stays subtracted in case a deployment turns it back on.
    """
    return memory["VmRSS"] - memory["RssShmem"]


def fill_core(core: ReplayCore, pool: Sequence[EpisodeData], episodes: int) -> None:
    for i in range(episodes):
        core.insert(dataclasses.replace(pool[i % len(pool)], actor_id="ref", seq=i))


def cluster_centroids(spec: TaskSpec) -> np.ndarray:
    """k centroids spread over the synthetic episodes' goal range (uniform in [−1, 1]³), so
    every cluster gets episodes, as a fitted model would give."""
    return generator(SEED, "bench", "centroids").uniform(
        -1.0, 1.0, size=(K_CLUSTERS, spec.goal_dim)).astype(np.float32)


# ----------------------------------------------------------------------------- the bench


@dataclasses.dataclass
class Alternation:
    """What `Bench.alternate` measured."""

    reference: list[tuple[float, float, float]] = dataclasses.field(default_factory=list)
    """(work done, wall seconds, CPU seconds of this thread) per reference slice."""
    windows: list[tuple[float, float]] = dataclasses.field(default_factory=list)
    """(start, end) monotonic times of each system slice."""
    system_cpu_s: list[float] = dataclasses.field(default_factory=list)
    """CPU seconds the system's child used in each slice (its threads included)."""

    @property
    def reference_rate(self) -> float:
        return sum(w for w, _, _ in self.reference) / sum(s for _, s, _ in self.reference)

    @property
    def reference_rate_per_cpu(self) -> float:
        return sum(w for w, _, _ in self.reference) / sum(c for _, _, c in self.reference)

    def system_rates(self, samples: Sequence[tuple[float, float]]) -> tuple[float, float]:
        """(wall-clock rate, rate per CPU second) of the system from (time, cumulative
        count) samples of its progress."""
        work = work_in_windows(samples, self.windows)
        return pooled_rate(self._slices(samples)), work / sum(self.system_cpu_s)

    def _slices(self, samples: Sequence[tuple[float, float]]) -> list[list[tuple[float, float]]]:
        return [[(t, c) for t, c in samples if a <= t <= b] for a, b in self.windows]

    def by_slice(self, samples: Sequence[tuple[float, float]], *, system: str,
                 reference: str) -> dict[str, list[float | None]]:
        """Per-slice rates and CPU shares of both sides, for the JSON details; keys are
        `<side>_<unit>_per_s_by_slice` and `<side>_cpu_share_by_slice` with `system` and
        `reference` naming the sides (e.g. "actor_steps", "raw_steps")."""
        return {
            f"{reference}_per_s_by_slice": [w / sec for w, sec, _ in self.reference],
            f"{system}_per_s_by_slice": [pooled_rate([x]) if len(x) > 1 else None
                                         for x in self._slices(samples)],
            f"{system.rsplit('_', 1)[0]}_cpu_share_by_slice": [
                c / (b - a) for c, (a, b) in zip(self.system_cpu_s, self.windows, strict=True)],
            f"{reference.rsplit('_', 1)[0]}_cpu_share_by_slice": [
                c / sec for _, sec, c in self.reference],
        }


class Bench:
    """The run: router, an observing client, the children, and the measurements so far."""

    def __init__(self, *, plan: Plan, workdir: Path) -> None:
        self.plan = plan
        self.workdir = workdir
        self.log_dir = workdir / "logs"
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.endpoint = free_endpoint()
        self.keys = RunKeys(RUN)
        self.figures: list[Figure] = []
        self.details: dict[str, Any] = {}
        self.phase_wall_s: dict[str, float] = {}
        self.children: list[Child] = []
        self.status = Latest()
        self.headers = Arrivals()
        self.weights = Arrivals()
        self.configs = {m: self._write_config(m) for m in plan.methods}
        # A replay of its own (own log folder) for the inserts without scenes.
        self.configs[NO_SCENE] = self._write_config("her", name=NO_SCENE, extra=[
            "replay.log_scene=false", f"run.run_dir={self.workdir / 'runs-no-scene'}"])
        self.spec = self.configs[plan.methods[0]][0].task.spec
        self.pool = episode_pool(self.spec, EPISODE_POOL)
        self.router: Transport | None = None
        self.observer: Transport | None = None
        self._fleet: SyntheticFleet | None = None

    # -- set-up ----------------------------------------------------------------------------
    def _write_config(self, method: str, *, name: str | None = None,
                      extra: Sequence[str] = ()) -> tuple[HercsConfig, Path]:
        p = self.plan
        config = apply_overrides(HercsConfig(), [
            f"run.name={RUN}", f"run.run_dir={self.workdir / 'runs'}", f"run.seed={SEED}",
            "task.name=push", f"run.method={method}", "replay.free_run=true",
            "training.max_policy_lag=-1",  # synthetic actors act with no weights version
            f"replay.buffer_transitions={p.buffer_transitions}",
            f"training.minibatches_per_cycle={p.minibatches_per_cycle}",
            "training.epochs=1000000",  # the learner runs until stopped
            f"actor.envs_per_process={p.actor_envs}",
            f"transport.connect=[{self.endpoint}]", f"transport.listen=[{self.endpoint}]",
            *extra,
        ])
        path = self.workdir / f"config-{name or method}.yaml"
        save_yaml(config, path)
        return config, path

    def __enter__(self) -> Bench:
        self.router = open_router([self.endpoint])
        self.observer = Transport.open(mode="client", connect=[self.endpoint],
                                       connect_timeout_s=30.0)
        self.observer.subscribe(self.keys.status, self._on_status, drop_oldest=True,
                                capacity=4)
        self.observer.subscribe(self.keys.inserted, self._on_header, capacity=4096)
        self.observer.subscribe(self.keys.weights, self._on_weights, capacity=256)
        return self

    def __exit__(self, *exc: object) -> None:
        for child in reversed(self.children):
            child.stop()
        self.children.clear()
        if self._fleet is not None:
            self._fleet.close()
        if self.observer is not None:
            self.observer.close()
        if self.router is not None:
            self.router.close()

    def _on_status(self, key: str, raw: bytes) -> None:
        self.status.set(pb.ReplayStatus.FromString(raw))

    def _on_header(self, key: str, raw: bytes) -> None:
        self.headers.add(pb.EpisodeHeader.FromString(raw).actor_id)

    def _on_weights(self, key: str, raw: bytes) -> None:
        self.weights.add(int(parse_message(raw, pb.Weights, max_bytes=MAX_REPLY_BYTES).version))

    @property
    def fleet(self) -> SyntheticFleet:
        """The synthetic actors (as many as the largest insert level), opened on first use."""
        if self._fleet is None:
            self._fleet = SyntheticFleet(size=max(self.plan.insert_actor_counts),
                                         endpoint=self.endpoint, pool=self.pool,
                                         task=self.spec.name)
        return self._fleet

    @property
    def client(self) -> Transport:
        assert self.observer is not None, "use Bench as a context manager"
        return self.observer

    # -- children ----------------------------------------------------------------------------
    def start(self, role: str, ident: str, method: str = "her") -> Child:
        child = Child(role=role, ident=ident, config_path=self.configs[method][1],
                      log_dir=self.log_dir)
        self.children.append(child)
        say(f"started {role} {ident} (pid {child.pid}), log {child.log_path}")
        return child

    def stop(self, child: Child) -> None:
        code = child.stop()
        self.children.remove(child)
        if code not in (0, -signal.SIGTERM):
            say(f"{child.role} {child.ident} exited with {code}; see {child.log_path}")

    def wait_status(self, pred: Callable[[pb.ReplayStatus], bool], *, what: str,
                    replay: Child, timeout_s: float = READY_TIMEOUT_S) -> pb.ReplayStatus:
        """The first ReplayStatus satisfying `pred`, checking that the replay lives."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            replay.check_alive()
            status = self.status.wait_for(pred, min(2.0, deadline - time.monotonic()))
            if status is not None:
                return status
        raise BenchError(f"no ReplayStatus with {what} within {timeout_s:g} s; end of "
                         f"{replay.log_path}:\n{replay.log_tail()}")

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        say(f"phase {name}")
        start = time.monotonic()
        try:
            yield
        finally:
            self.phase_wall_s[name] = round(time.monotonic() - start, 1)

    # -- alternation ---------------------------------------------------------------------------
    def alternate(self, child: Child, *, rounds: int, slice_s: float,
                  reference: Callable[[float], tuple[float, float, float]]) -> Alternation:
        """Reference and system in turns: `reference(slice_s)` runs here while `child` is
        paused, then `child` runs alone for `slice_s`; `rounds` times, and one more reference
        slice at the end, so each system slice sits between two reference slices.

        Short alternating slices make both sides see the same background load, which on a
        shared machine drifts within seconds.
        """
        out = Alternation()
        child.pause()
        try:
            for _ in range(rounds):
                out.reference.append(reference(slice_s))
                cpu = child.cpu_seconds()
                child.resume()
                start = time.monotonic()
                time.sleep(slice_s)
                end = time.monotonic()
                child.pause()
                out.windows.append((start, end))
                out.system_cpu_s.append(child.cpu_seconds() - cpu)
            out.reference.append(reference(slice_s))
        finally:
            child.resume()
        child.check_alive()
        return out

    # -- 1. env steps ------------------------------------------------------------------------
    def raw_env(self) -> Callable[[float], tuple[float, float, float]]:
        """Raw FetchPush stepping with uniform random actions; returns run(seconds) ->
        (env steps, seconds, CPU seconds). Resets every T steps, as an actor's episodes do;
        one untimed episode first. The env lives as long as the process."""
        spec = self.spec
        env = make_env(spec)
        rng = generator(SEED, "bench", "raw-env")
        env.reset(seed=int_seed(SEED, "bench", "raw-env"))
        T, low, high = spec.episode_steps, -spec.max_action, spec.max_action
        for _ in range(T):
            env.step(rng.uniform(low, high, spec.action_dim).astype(np.float32))

        def run(seconds: float) -> tuple[float, float, float]:
            steps, start, cpu = 0, time.perf_counter(), time.thread_time()
            while time.perf_counter() - start < seconds:
                env.reset()
                for _ in range(T):
                    env.step(rng.uniform(low, high, spec.action_dim).astype(np.float32))
                steps += T
            return float(steps), time.perf_counter() - start, time.thread_time() - cpu

        return run

    def env_phase(self) -> None:
        p, T = self.plan, self.spec.episode_steps
        raw = self.raw_env()
        actor = self.start("actor", ACTOR_ID)

        def is_ours(actor_id: str) -> bool:
            # The wire id is `<ident>@<incarnation>` (actors/service.py).
            return actor_id.partition("@")[0] == ACTOR_ID

        try:
            self.headers.wait_count(is_ours, p.actor_warmup_episodes, timeout_s=READY_TIMEOUT_S,
                                    alive=actor)
            turns = self.alternate(actor, rounds=p.env_rounds, slice_s=p.env_slice_s,
                                   reference=raw)
        finally:
            self.stop(actor)
        arrivals = [t for t, actor_id in self.headers.snapshot() if is_ours(actor_id)]
        acked = [(t, (i + 1) * T) for i, t in enumerate(arrivals)]  # cumulative env steps
        ours, ours_cpu = turns.system_rates(acked)
        reference, reference_cpu = turns.reference_rate, turns.reference_rate_per_cpu
        say(f"env steps/s: actor {ours:,.0f}, raw {reference:,.0f}; per CPU-second: actor "
            f"{ours_cpu:,.0f}, raw {reference_cpu:,.0f}")
        self.details["env"] = {
            **turns.by_slice(acked, system="actor_steps", reference="raw_steps"),
            "slice_s": p.env_slice_s, "rounds": p.env_rounds,
            "actor_policy": "initial weights (no learner runs in this phase); the same "
                            "network, so the same inference cost as a trained one",
        }
        slices = f"in {p.env_slice_s:g} s slices alternating with the actor's (paused meanwhile)"
        self.figures.append(Figure(
            key="env_steps_per_s", name=f"env steps/s, one actor ({p.actor_envs} envs)",
            unit="steps/s", ours=ours, reference=reference,
            ours_what=f"one `hercs actor` process stepping {p.actor_envs} envs "
                      "(`actor.envs_per_process`; batched policy inference, exploration, "
                      "inserts acked over Zenoh), acked episodes × 50 per second at the replay",
            reference_what=f"raw FetchPush-v4 steps with random actions in one process, {slices}",
            target=Target("ratio_at_least", 0.9)))
        self.figures.append(Figure(
            key="env_steps_per_cpu_s",
            name=f"env steps per CPU-second, one actor ({p.actor_envs} envs)",
            unit="steps/CPU-s", ours=ours_cpu, reference=reference_cpu,
            ours_what="the same acked steps over the CPU time of the actor process (all its "
                      "threads) in its slices: the rate it would reach on a core of its own",
            reference_what="raw steps over the CPU time of the stepping thread",
            target=Target("ratio_at_least", 0.95)))

    # -- 2. learner updates --------------------------------------------------------------------
    def reference_learner(self, batches: Sequence[SampleBatch]
                          ) -> Callable[[float], tuple[float, float, float]]:
        """A `LearnerLoop` in this process; returns run(seconds) -> (updates, seconds, CPU
        seconds), whole cycles only. One untimed cycle first."""
        config = self.configs["her"][0]
        loop = LearnerLoop(config=config, learner=DDPGLearner(
            spec=self.spec, config=config.ddpg, seed=config.run.seed))
        loop.step(batches[0])
        turn = 0

        def run(seconds: float) -> tuple[float, float, float]:
            nonlocal turn
            updates, start, cpu = 0, time.perf_counter(), time.thread_time()
            while time.perf_counter() - start < seconds:
                batch = batches[turn % len(batches)]
                loop.step(batch)
                updates += len(batch.minibatches)
                turn += 1
            return float(updates), time.perf_counter() - start, time.thread_time() - cpu

        return run

    def local_batches(self, count: int) -> list[SampleBatch]:
        """Batches as the learner gets them, sampled here from a local core (untimed)."""
        config = self.configs["her"][0]
        core = ReplayCore(config=config, rng=generator(SEED, "bench", "learner-core"))
        fill_core(core, self.pool, max(self.plan.learner_min_episodes, EPISODE_POOL))
        out = []
        for _ in range(count):
            result = core.sample(self.plan.minibatches_per_cycle, config.ddpg.batch_size)
            o_stats, g_stats = core.normalizer_state()
            out.append(SampleBatch(
                minibatches=result.minibatches,
                o_stats=o_stats, g_stats=g_stats))
        return out

    def top_up(self, replay: Child, episodes: int) -> None:
        """Insert synthetic episodes until the replay holds at least `episodes`."""
        held = int(self.wait_status(lambda s: True, what="any size", replay=replay)
                   .size_episodes)
        if held >= episodes:
            return
        with self.fleet.running(1) as (actor,):
            before = len(actor.acks)
            while len(actor.acks) - before < episodes - held and actor.error is None:
                replay.check_alive()
                time.sleep(0.05)

    def learner_phase(self, replay: Child) -> None:
        p = self.plan
        torch.set_num_threads(1)  # as learner.service does
        self.top_up(replay, p.learner_min_episodes)
        reference = self.reference_learner(self.local_batches(4))
        self.weights.clear()
        learner = self.start("learner", "bench-learner")
        try:
            self.weights.wait_count(lambda v: v >= p.learner_warmup_cycles, 1,
                                    timeout_s=READY_TIMEOUT_S, alive=learner)
            turns = self.alternate(learner, rounds=p.learner_rounds,
                                   slice_s=p.learner_slice_s, reference=reference)
        finally:
            self.stop(learner)
        progress = [(t, v * p.minibatches_per_cycle) for t, v in self.weights.snapshot()]
        ours, ours_cpu = turns.system_rates(progress)
        reference_rate, reference_cpu = turns.reference_rate, turns.reference_rate_per_cpu
        say(f"updates/s: learner service {ours:.1f}, in process {reference_rate:.1f}; per "
            f"CPU-second: service {ours_cpu:.1f}, in process {reference_cpu:.1f}")
        self.details["learner"] = {
            **turns.by_slice(progress, system="service_updates", reference="reference_updates"),
            "slice_s": p.learner_slice_s, "rounds": p.learner_rounds,
            "minibatches_per_cycle": p.minibatches_per_cycle, "batch_size": 256,
            "torch_threads": 1,
        }
        self.figures.append(Figure(
            key="learner_updates_per_s", name="learner updates/s", unit="updates/s",
            ours=ours, reference=reference_rate,
            ours_what=f"the `hercs learner` process pulling {p.minibatches_per_cycle}×256 "
                      "batches over Zenoh (prefetch depth 2), weights versions per second × "
                      f"{p.minibatches_per_cycle}",
            reference_what="`LearnerLoop.step` in one process, one torch thread, on batches "
                           "sampled beforehand from a local ReplayCore, in "
                           f"{p.learner_slice_s:g} s slices alternating with the learner's "
                           "(paused meanwhile)",
            target=Target("ratio_at_least", 0.95)))
        self.figures.append(Figure(
            key="learner_updates_per_cpu_s", name="learner updates per CPU-second",
            unit="updates/CPU-s", ours=ours_cpu, reference=reference_cpu,
            ours_what="the same updates over the CPU time of the learner process (update "
                      "thread, prefetch and decoding, weights broadcast) in its slices",
            reference_what="in-process updates over the CPU time of the updating thread"))

    def roofline_figures(self) -> None:
        """The update against this core's GEMM limit, per precision (bench/learner.py, where
        the GEMM replay that explains the gap also runs)."""
        p, spec, config = self.plan, self.spec, self.configs["her"][0].ddpg
        rng = np.random.default_rng(SEED)
        batches = [make_batch(spec, config.batch_size, rng) for _ in range(16)]
        repeats = batches * max(1, p.roofline_updates // len(batches))
        flops = 0
        targets = {"fp32": 0.85, "bf16": 0.8}
        for precision, dtype in (("fp32", torch.float32), ("bf16", torch.bfloat16)):
            learner = DDPGLearner(spec=spec, config=config, seed=SEED, precision=precision)
            flops = flops or update_flops(learner, batches[0])
            limit = gemm_rate(config.batch_size, config.hidden_size, dtype,
                              p.roofline_gemms) / flops
            rate = update_rate(learner, repeats)
            say(f"learner {precision}: {rate:.1f} updates/CPU-s against a GEMM limit of "
                f"{limit:.1f} ({rate / limit:.2f})")
            self.figures.append(Figure(
                key=f"learner_roofline_{precision}",
                name=f"learner update vs its {precision} GEMM limit", unit="updates/CPU-s",
                ours=rate, reference=limit,
                ours_what=f"`DDPGLearner.update` with learner.precision={precision}, "
                          f"B = {config.batch_size}, one torch thread, in process",
                reference_what=f"this core's {config.batch_size}×{config.hidden_size}×"
                               f"{config.hidden_size} {precision} GEMM rate ÷ the update's "
                               f"{flops / 1e9:.3f} GFLOP (torch's FLOP counter), measured "
                               "in the same run",
                target=Target("ratio_at_least", targets[precision])))

    # -- 3. inserts and the fill ---------------------------------------------------------------
    def insert_rates(self, replay: Child, counts: Sequence[int], *, label: str = ""
                     ) -> dict[str, Any]:
        """Per insert level: acked episodes/s (`episodes_per_s`), ack latency and the replay's
        CPU share (`ack_latency`), episodes per replay CPU-second; the phase's `details`."""
        p = self.plan
        rates: dict[int, float] = {}
        per_cpu: dict[int, float] = {}
        latency: dict[int, dict[str, float]] = {}
        for n in counts:
            with self.fleet.running(n):
                time.sleep(p.insert_warmup_s)
                cpu0, opened = replay.cpu_seconds(), time.monotonic()
                time.sleep(p.insert_window_s)
                cpu1, closed = replay.cpu_seconds(), time.monotonic()
            acks = self.fleet.acks_between(opened, closed)
            if not acks:
                raise BenchError(f"no insert acked in {p.insert_window_s:g} s with {n} actors")
            rates[n] = len(acks) / (closed - opened)
            per_cpu[n] = len(acks) / max(cpu1 - cpu0, 1e-9)
            lat_ms = [a[2] * 1e3 for a in acks]
            latency[n] = {"p50_ms": percentile(lat_ms, 50), "p99_ms": percentile(lat_ms, 99),
                          "replay_cpu_share": (cpu1 - cpu0) / (closed - opened)}
            say(f"inserts{label}, {n} synthetic actor(s): {rates[n]:.1f} episodes/s acked, "
                f"ack latency p50 {latency[n]['p50_ms']:.1f} ms, replay CPU "
                f"{latency[n]['replay_cpu_share']:.2f} → {per_cpu[n]:.0f} episodes per "
                "replay CPU-second")
        return {"episodes_per_s": rates, "ack_latency": latency,
                "episodes_per_replay_cpu_s": per_cpu, "window_s": p.insert_window_s}

    def insert_phase(self, replay: Child) -> None:
        p = self.plan
        details = self.details["inserts"] = self.insert_rates(replay, p.insert_actor_counts)
        rates, per_cpu, latency = (details["episodes_per_s"], details["episodes_per_replay_cpu_s"],
                                   details["ack_latency"])
        base = rates[p.insert_actor_counts[0]]
        for n in p.insert_actor_counts:
            self.figures.append(Figure(
                key=f"inserts_per_s_{n}_actors", name=f"inserts/s acked, {n} actor(s)",
                unit="episodes/s", ours=rates[n], reference=base,
                ours_what=f"{n} concurrent synthetic actor(s), each with its own Zenoh session "
                          f"and one Push episode in flight, acked episodes per second (the "
                          f"replay used {latency[n]['replay_cpu_share']:.2f} CPU: "
                          f"{per_cpu[n]:.0f} episodes per replay CPU-second)",
                reference_what=f"the same with {p.insert_actor_counts[0]} actor (ratio = "
                               "speed-up)",
                target=Target("ours_at_least", 1000.0) if n >= 8 else None))

    def insert_no_scene_phase(self) -> None:
        """The largest insert levels again, into a fresh replay with `replay.log_scene=false`:
        what drawing each episode's Foxglove scene costs the replay (docs/PERFORMANCE.md §6)."""
        p = self.plan
        replay = self.start("replay", "bench-replay-no-scene", NO_SCENE)
        try:
            self.status.clear()
            self.wait_status(lambda s: True, what="the replay without scenes up", replay=replay)
            details = self.details["inserts_no_scene"] = self.insert_rates(
                replay, p.insert_no_scene_counts, label=" without scenes")
        finally:
            self.stop(replay)
        rates, per_cpu, latency = (details["episodes_per_s"], details["episodes_per_replay_cpu_s"],
                                   details["ack_latency"])
        with_scene = self.details["inserts"]["episodes_per_s"]
        for n in p.insert_no_scene_counts:
            self.figures.append(Figure(
                key=f"inserts_per_s_{n}_actors_no_scene",
                name=f"inserts/s acked, {n} actor(s), replay.log_scene=false",
                unit="episodes/s", ours=rates[n], reference=with_scene[n],
                ours_what=f"as above with {n} actor(s), into a replay of its own that logs "
                          "every episode but draws no Foxglove scene (the replay used "
                          f"{latency[n]['replay_cpu_share']:.2f} CPU: {per_cpu[n]:.0f} "
                          "episodes per replay CPU-second)",
                reference_what=f"the same {n} actor(s) into the replay drawing scenes, above "
                               "(ratio = what the scenes cost)",
                target=Target("ours_at_least", 1000.0) if n >= 8 else None))

    def fill(self, replay: Child) -> int:
        """Insert synthetic episodes until the ring is full; returns episodes in the store."""
        capacity = self.configs["her"][0].capacity_episodes
        n = len(self.fleet.actors)
        start, last_report = time.monotonic(), time.monotonic()
        with self.fleet.running(n) as actors:
            while self.fleet.newest_episode_id() + 1 < capacity:
                replay.check_alive()
                if any(a.error is not None for a in actors):
                    break  # raised when the block exits
                if time.monotonic() - last_report > 15:
                    last_report = time.monotonic()
                    say(f"filling: {self.fleet.newest_episode_id() + 1:,}/{capacity:,} "
                        "episodes inserted")
                time.sleep(0.1)
        status = self.wait_status(lambda s: s.size_episodes >= capacity,
                                  what=f"size {capacity}", replay=replay)
        wall = time.monotonic() - start
        say(f"filled: {status.size_transitions:,} transitions ({wall:.0f} s)")
        self.details["fill"] = {"episodes": int(status.size_episodes),
                                "transitions": int(status.size_transitions),
                                "inserted_total": int(status.inserts), "actors": n,
                                "wall_s": round(wall, 1)}
        return int(status.size_episodes)

    # -- 4. sample latency -----------------------------------------------------------------------
    def sample_over_zenoh(self, method: str) -> list[float]:
        """Per-request seconds, request sent → reply bytes received, after a warm-up."""
        p = self.plan
        out: list[float] = []
        for i in range(p.sample_warmup_requests + p.sample_requests):
            request = pb.SampleRequest(
                schema_version=SCHEMA_VERSION, run=RUN, learner_id="bench", request_id=i + 1,
                num_minibatches=p.sample_minibatches, batch_size=p.sample_batch_size)
            payload = request.SerializeToString()
            start = time.perf_counter()
            raw = self.client.request(self.keys.sample, payload, timeout_s=REQUEST_TIMEOUT_S)
            elapsed = time.perf_counter() - start
            batch = parse_message(raw, pb.Batch, max_bytes=MAX_REPLY_BYTES)
            if len(batch.minibatches) != p.sample_minibatches:
                raise BenchError(f"{method}: a Batch of {len(batch.minibatches)} minibatches, "
                                 f"asked for {p.sample_minibatches}")
            if method.endswith("-cs") and batch.cluster_model_version < 1:
                raise BenchError(f"{method}: the replay sampled without a cluster model")
            if i >= p.sample_warmup_requests:
                out.append(elapsed)
        return out

    def sample_in_process(self, method: str, episodes: int) -> list[float]:
        """Per-request seconds of `ReplayCore.sample` here, on a store of the same size."""
        p = self.plan
        config = self.configs[method][0]
        core = ReplayCore(config=config, rng=generator(SEED, "bench", "sample-core"))
        fill_core(core, self.pool, episodes)
        if config.run.uses_clusters:
            core.set_cluster_model(ClusterModel(version=1, centroids=cluster_centroids(
                self.spec), n_goals=config.cluster.fgb_size, failures_seen=episodes))
        out = []
        for i in range(p.sample_warmup_requests + p.sample_requests):
            start = time.perf_counter()
            core.sample(p.sample_minibatches, p.sample_batch_size)
            if i >= p.sample_warmup_requests:
                out.append(time.perf_counter() - start)
        return out

    def sample_figures(self, method: str, episodes: int) -> None:
        p = self.plan
        ours_s = self.sample_over_zenoh(method)
        ref_s = self.sample_in_process(method, episodes)
        stats = {}
        for per, divide in (("minibatch", p.sample_minibatches), ("request", 1)):
            for q in (50, 99):
                ours = percentile(ours_s, q) * 1e3 / divide
                reference = percentile(ref_s, q) * 1e3 / divide
                stats[f"p{q}_{per}_ms"] = {"ours": ours, "reference": reference}
                size = f"{p.sample_minibatches}×{p.sample_batch_size}"
                self.figures.append(Figure(
                    key=f"sample_p{q}_{per}_{method}",
                    name=f"sample p{q} per {per}, {method}", unit="ms", ours=ours,
                    reference=reference,
                    ours_what=f"SampleRequest of {size} over Zenoh to the replay holding "
                              f"{episodes * self.spec.episode_steps:,} transitions, request "
                              f"→ reply bytes at a client"
                              + (", ÷ 40" if per == "minibatch" else ""),
                    reference_what=f"`ReplayCore.sample` of {size} in one process on a store "
                                   "of the same size" + (", ÷ 40" if per == "minibatch"
                                                         else ""),
                    target=Target("ours_at_most", 1.0) if (q, per) == (99, "minibatch")
                    else None))
        self.details.setdefault("samples", {})[method] = {
            "requests": len(ours_s), "stored_episodes": episodes, **stats}
        say(f"sample {method}: p50 {stats['p50_minibatch_ms']['ours']:.2f} ms, p99 "
            f"{stats['p99_minibatch_ms']['ours']:.2f} ms per minibatch over Zenoh "
            f"(in process p99 {stats['p99_minibatch_ms']['reference']:.2f} ms)")

    def publish_cluster_model(self, replay: Child) -> None:
        centroids = cluster_centroids(self.spec)
        publisher = self.client.publisher(self.keys.cluster_model, latest=True, block=True)
        fgb_size = self.configs["her-cs"][0].cluster.fgb_size
        model = ClusterModel(version=1, centroids=centroids, n_goals=fgb_size,
                             failures_seen=fgb_size)
        publisher.put(cluster_model_to_msg(model).SerializeToString())
        status = self.wait_status(lambda s: s.cluster_model_version >= 1,
                                  what="cluster model v1 adopted", replay=replay)
        self.details.setdefault("samples", {})["her-cs_cluster_sizes"] = list(
            status.cluster_sizes)

    # -- 5. memory -------------------------------------------------------------------------------
    def memory_figures(self, *, idle: dict[str, float], filled: dict[str, float],
                       episodes: int) -> None:
        per_episode = store_bytes_per_episode(self.spec)
        raw_mib = per_episode * episodes / 2**20
        growth_mib = own_rss_mib(filled) - own_rss_mib(idle)
        total_mib = filled["VmRSS"]
        transitions = episodes * self.spec.episode_steps
        self.details["memory"] = {
            "idle_mib": idle, "filled_mib": filled, "raw_bytes_per_episode": per_episode,
            "stored_episodes": episodes, "raw_mib": raw_mib,
            "own_rss_growth_mib": growth_mib}
        self.figures.append(Figure(
            key="replay_rss_growth", name="replay RSS growth", unit="MiB",
            ours=growth_mib, reference=raw_mib,
            ours_what=f"VmRSS − RssShmem of the replay holding {transitions:,} transitions "
                      "after serving the sample requests, minus the same when it had just "
                      "started (empty store); RssShmem = the Zenoh shared-memory pools of the "
                      "local senders, mapped by the replay",
            reference_what=f"bytes of the store's arrays for {episodes:,} episodes "
                           f"({per_episode:,} B each: obs, ag, g, actions, metadata)",
            target=Target("ratio_at_most", 1.5)))
        self.figures.append(Figure(
            key="replay_rss_total", name="replay RSS total", unit="MiB",
            ours=total_mib, reference=raw_mib,
            ours_what=f"VmRSS of the replay holding {transitions:,} transitions, nothing "
                      "subtracted (interpreter, libraries, Zenoh shared-memory pools "
                      f"{filled['RssShmem']:.0f} MiB included)",
            reference_what="bytes of the store's arrays, as above"))

    # -- the whole run ---------------------------------------------------------------------------
    def run(self) -> None:
        with self.phase("replay start"):
            replay = self.start("replay", "bench-replay-her", "her")
            self.wait_status(lambda s: True, what="the replay up", replay=replay)
            time.sleep(1.0)  # let start-up allocations settle before the idle reading
            idle = replay.memory_mib()
            say(f"idle replay RSS {idle['VmRSS']:.1f} MiB")
        # The replay's RSS after each phase, to see where its memory goes.
        trace = self.details["replay_memory_mib_after"] = {"start": idle}
        with self.phase("env steps"):
            self.env_phase()
        trace["env steps"] = replay.memory_mib()
        with self.phase("learner updates"):
            self.learner_phase(replay)
        with self.phase("learner roofline"):
            self.roofline_figures()
        trace["learner updates"] = replay.memory_mib()
        with self.phase("inserts"):
            self.insert_phase(replay)
        trace["inserts"] = replay.memory_mib()
        with self.phase("fill"):
            episodes = self.fill(replay)
        trace["fill"] = replay.memory_mib()
        with self.phase("sample her"):
            self.sample_figures("her", episodes)
            filled = replay.memory_mib()
        trace["sample her"] = filled
        self.stop(replay)
        self.memory_figures(idle=idle, filled=filled, episodes=episodes)
        for method in self.plan.methods[1:]:
            with self.phase(f"sample {method}"):
                self.status.clear()
                replay = self.start("replay", f"bench-replay-{method}", method)
                self.wait_status(lambda s: s.size_episodes >= episodes,
                                 what=f"{episodes} episodes recovered from the log",
                                 replay=replay)
                if self.configs[method][0].run.uses_clusters:
                    self.publish_cluster_model(replay)
                self.sample_figures(method, episodes)
                self.details.setdefault("replay_memory_mib_recovered", {})[method] = (
                    replay.memory_mib())
                self.stop(replay)
        with self.phase("inserts without scenes"):
            self.insert_no_scene_phase()


# ----------------------------------------------------------------------------- report


def machine_description() -> dict[str, Any]:
    model = cpu_info().get("model name", platform.processor() or "unknown CPU")
    ram_gib = float("nan")
    with contextlib.suppress(OSError, ValueError):
        ram_gib = parse_proc_status_kib(Path("/proc/meminfo").read_text(), "MemTotal") / 2**20
    versions = {}
    for dist in ("torch", "mujoco", "eclipse-zenoh", "numpy", "gymnasium", "gymnasium-robotics",
                 "protobuf", "mcap"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = None
    return {"cpu_count": os.cpu_count(), "cpu_model": model, "ram_gib": ram_gib,
            "python": platform.python_version(), "platform": platform.platform(),
            "versions": versions}


NOTES = [
    "The replay runs with `replay.free_run=true` in every phase (no learner while the actor "
    "is measured, no actor while the learner is): the sample-to-insert rate limiter would "
    "otherwise hold inserts or samples, and the phase would measure the limiter.",
    "Env steps and learner updates: system and reference alternate in short slices (each "
    "system slice between two reference slices) and each side's rate is pooled over its "
    "slices, so a drift of the machine's background load hits both sides. During a reference "
    "slice the system's process is paused with SIGSTOP (≤ 4 s, inside Zenoh's 10 s lease). "
    "The per-slice rates and CPU shares are in the JSON (`details`).",
    "Per CPU-second rows divide the same work by the CPU time used for it (/proc/<pid>/stat "
    "of the system's process, all threads; `time.thread_time()` of the reference loop): on a "
    "loaded machine they show the cost per step or update without the scheduling noise.",
    "Every service is a real process (`python -m apps.cli <role> --config … --id …`) connected "
    "as a client to a Zenoh router embedded in the benchmark process on a free loopback port.",
    "Env steps/s of the actor are counted where they become useful: acked episodes on "
    "`replay/inserted`, (n − 1) episodes × 50 steps over the time between the first and the "
    "last one in the window. No learner runs then, so the actor acts with its initial "
    "weights: the same network, so the same inference cost.",
    "Learner updates/s are counted from its `weights` broadcasts, one per cycle of "
    "`minibatches_per_cycle` updates, after its first cycles (start-up, first batch).",
    "Learner against its GEMM limit: in this process after the learner phase (the learner "
    "service stopped), one torch thread, per precision: `DDPGLearner.update` per CPU-second "
    "against (this core's 256×256×256 GEMM rate in that precision) ÷ (the update's FLOPs, "
    "torch's FLOP counter); `bench/learner.py` measures the same and also replays the "
    "update's own products alone, which shows where the gap is (docs/PERFORMANCE.md §4).",
    "Synthetic actors insert pre-generated random Push episodes (valid shapes and values); "
    "each episode is appended to the replay's MCAP log and fsynced before its ack, as always. "
    "The replay serves inserts one at a time, so on a busy machine the rate follows the CPU "
    "share the replay gets; `details.inserts` also gives episodes per replay CPU-second.",
    "Inserts without scenes: after the sample phases, a fresh replay (its own log folder, "
    "`replay.log_scene=false`: every episode is logged and fsynced before its ack, no "
    "Foxglove scene is drawn) takes the largest insert levels from the same synthetic actors; "
    "the ratio to the same level with scenes is what drawing them costs.",
    "Sample latency: the `her` replay is the one filled over Zenoh; the `her-cs` replay is the "
    "same run restarted with `run.method=her-cs`, refilled from its own episode log (crash "
    "recovery) and given a k=8 cluster model on `cluster/model`; the reply is not decoded "
    "inside the timing.",
    "Replay RSS growth = (VmRSS − RssShmem) from /proc/<pid>/status of the filled replay "
    "after it served the `her` sample requests, minus the same just after start (empty store; "
    "`np.zeros` commits pages only when written). RssShmem is left out because it holds Zenoh's "
    "shared-memory pools (on by default in Zenoh 1.x: 16 MiB per local session that sends "
    "messages above 3 KiB; off in hercs sessions since this benchmark found them), which the "
    "replay maps from its senders: shared pages that grow with the number of local peers, not "
    "with the data stored. Raw bytes = stored episodes × "
    "the bytes of one episode in the store's arrays (obs, ag, g, actions and the metadata "
    "columns). The phase-by-phase memory of the replay is in `details`.",
]


def build_report(bench: Bench, *, command: str, started: float, load_start: tuple,
                 date: str) -> dict[str, Any]:
    machine = machine_description()
    machine["load_avg_start"] = list(load_start)
    machine["load_avg_end"] = list(os.getloadavg())
    return {
        "benchmark": "throughput", "mode": bench.plan.mode, "date": date,
        "git_commit": git_commit(), "command": command, "machine": machine,
        "plan": dataclasses.asdict(bench.plan),
        "figures": [f.to_dict() for f in bench.figures],
        "details": bench.details, "phase_wall_s": bench.phase_wall_s,
        "total_wall_s": round(time.monotonic() - started, 1), "notes": NOTES,
    }


def write_report(report: dict[str, Any], out_dir: Path) -> str:
    """Writes throughput.json and throughput.md to `out_dir`; returns the markdown."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "throughput.json").write_text(json.dumps(report, indent=2, default=str) + "\n")
    markdown = render_markdown(report)
    (out_dir / "throughput.md").write_text(markdown)
    return markdown


# ----------------------------------------------------------------------------- CLI


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true",
                   help="CI mode: tiny sizes and windows (well under a minute)")
    p.add_argument("--out", default=None,
                   help="folder for throughput.json and throughput.md (default docs/results; "
                        "a temporary folder with --quick)")
    p.add_argument("--keep-workdir", action="store_true",
                   help="keep the run folder (logs, episode log) even when all went well")
    return p


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    started, load_start = time.monotonic(), os.getloadavg()
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    command = shlex.join(["python", "bench/throughput.py",
                          *(sys.argv[1:] if argv is None else argv)])
    plan = QUICK if args.quick else FULL
    out_dir = Path(args.out) if args.out else (
        Path(tempfile.mkdtemp(prefix="hercs-throughput-out-")) if args.quick
        else REPO / "docs" / "results")
    workdir = Path(tempfile.mkdtemp(prefix="hercs-throughput-"))
    signal.signal(signal.SIGTERM, _interrupt)  # so the finally blocks stop the children
    say(f"{plan.mode} mode; work folder {workdir}")
    ok = False
    try:
        with Bench(plan=plan, workdir=workdir) as bench:
            say(f"router on {bench.endpoint}")
            bench.run()
        report = build_report(bench, command=command, started=started, load_start=load_start,
                              date=date)
        markdown = write_report(report, out_dir)
        ok = True
    except (BenchError, KeyboardInterrupt) as exc:
        say(f"stopped: {exc}")
        return 1
    finally:
        if ok and not args.keep_workdir:
            shutil.rmtree(workdir, ignore_errors=True)
        else:
            say(f"logs kept in {workdir / 'logs'}")
    print(markdown, end="")
    say(f"wrote {out_dir / 'throughput.json'} and {out_dir / 'throughput.md'} "
        f"({report['total_wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
