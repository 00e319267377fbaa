"""run_profile.md from the summary: CPU seconds per epoch by process, by function group, and
each process's heaviest frames."""

from __future__ import annotations

from typing import Any

ROLE_ORDER = ("learner", "replay", "actor-0", "evaluator-0", "clusterer", "up")


def _roles(summary: dict[str, Any]) -> list[str]:
    found = summary["cpu_s_per_epoch_by_process"]
    return [r for r in ROLE_ORDER if r in found] + sorted(set(found) - set(ROLE_ORDER))


def render(summary: dict[str, Any]) -> str:
    roles = _roles(summary)
    epochs, wall = summary["epochs"], summary["wall_s"]
    per_epoch = wall / max(epochs, 1)
    by_process = summary["cpu_s_per_epoch_by_process"]
    run_cpu = sum(by_process.values())
    machine = summary.get("machine", {})
    lines = [
        "# Where a run's time goes (`python -m bench.perf.run_profile`)",
        "",
        f"{summary.get('date', '?')}, commit `{summary.get('commit', '?')}`, "
        f"{machine.get('cpu', '?')}, {summary['cores']} cores; "
        f"py-spy at {summary.get('rate', '?')} Hz on every process (`--subprocesses --native`)"
        f"{', quick mode' if summary.get('quick') else ''}.",
        "",
        f"Run: `{summary['command']}`: {epochs} epoch(s) in {wall:.1f} s under the profiler "
        f"({per_epoch:.1f} s per epoch, start-up included; the run's own clock: "
        f"{summary['run_wall_s']:.1f} s)."
        + (f" py-spy crashed by itself {len(crashes)} time(s) ({', '.join(crashes)}): each "
           "such run was stopped and the profile taken afresh; this one is whole."
           if (crashes := summary.get("profiler_crashes")) else ""),
        "",
        "## CPU seconds per epoch, by process",
        "",
        "| process | CPU-s per epoch | share of the run's CPU |",
        "|---|---:|---:|",
        *(f"| {r} | {by_process[r]:.2f} | {by_process[r] / max(run_cpu, 1e-9):.0%} |"
          for r in roles),
        f"| **all** | **{run_cpu:.2f}** | 100% |",
        f"| idle (cores × wall − every process's CPU) | {summary['idle_s_per_epoch']:.2f} | |",
        f"| other load on the machine | {summary['other_load_s_per_epoch']:.2f} | |",
        "",
        "Mean busy share per core: " + ", ".join(
            f"{name} {share:.0%}" for name, share in sorted(summary["core_busy_mean"].items()))
        + " (the time series: run_profile_cores.csv).",
        "",
        "## CPU seconds per epoch, by function group",
        "",
        "A process's CPU time (/proc) split by the share of its busy py-spy samples in each "
        "group; samples of threads parked in native waits are idle and not counted.",
        "",
        "| group | " + " | ".join(roles) + " | all |",
        "|---|" + "---:|" * (len(roles) + 1),
    ]
    for group, row in summary["cpu_s_per_epoch_by_group"].items():
        cells = [f"{row[r]:.2f}" if r in row else "" for r in roles]
        lines.append(f"| {group} | " + " | ".join(cells) + f" | {sum(row.values()):.2f} |")
    lines += ["", "## Each process's heaviest innermost frames (the flame graphs' summary)", ""]
    for role in roles:
        frames = summary["top_frames"].get(role)
        if not frames:
            continue
        lines.append(f"- **{role}**: " + "; ".join(f"`{frame}` {share:.0%}"
                                                    for frame, share in frames[:8]))
    return "\n".join(lines) + "\n"
