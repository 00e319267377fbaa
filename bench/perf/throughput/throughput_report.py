"""The report: each figure with its reference and target, the verdicts, the markdown table,
the notes and the machine, written as throughput.json and throughput.md."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import platform
import time
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any, Literal

from bench.common import cpu_info, git_commit
from bench.perf.throughput.plan import Plan

MEETS = "meets target"
BELOW = "below target"
NO_TARGET = "no target"

TargetKind = Literal["ratio_at_least", "ratio_at_most", "ours_at_most", "ours_at_least"]


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
    "Every service is a real process (`python -m hercs.apps.cli <role> --config … --id …`) "
    "connected as a client to a Zenoh router embedded in the benchmark process on a free "
    "loopback port.",
    "Env steps/s of the actor are counted where they become useful: acked episodes on "
    "`replay/inserted`, (n − 1) episodes × 50 steps over the time between the first and the "
    "last one in the window. No learner runs then, so the actor acts with its initial "
    "weights: the same network, so the same inference cost.",
    "Learner updates/s are counted from its `weights` broadcasts, one per cycle of "
    "`minibatches_per_cycle` updates, after its first cycles (start-up, first batch).",
    "Learner against its GEMM limit: in this process after the learner phase (the learner "
    "service stopped), one torch thread, per precision: `DDPGLearner.train` per CPU-second "
    "against (this core's 256×256×256 GEMM rate in that precision) ÷ (the update's FLOPs, "
    "torch's FLOP counter); `bench/perf/learner.py` measures the same and also replays the "
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


def build_report(*, plan: Plan, figures: Sequence[Figure], details: dict[str, Any],
                 phase_wall_s: dict[str, float], command: str, started: float,
                 load_start: tuple, date: str) -> dict[str, Any]:
    machine = machine_description()
    machine["load_avg_start"] = list(load_start)
    machine["load_avg_end"] = list(os.getloadavg())
    return {
        "benchmark": "throughput", "mode": plan.mode, "date": date,
        "git_commit": git_commit(), "command": command, "machine": machine,
        "plan": dataclasses.asdict(plan),
        "figures": [f.to_dict() for f in figures],
        "details": details, "phase_wall_s": phase_wall_s,
        "total_wall_s": round(time.monotonic() - started, 1), "notes": NOTES,
    }


def write_report(report: dict[str, Any], out_dir: Path) -> str:
    """Writes throughput.json and throughput.md to `out_dir`; returns the markdown."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "throughput.json").write_text(json.dumps(report, indent=2, default=str) + "\n")
    markdown = render_markdown(report)
    (out_dir / "throughput.md").write_text(markdown)
    return markdown
