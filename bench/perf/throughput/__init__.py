"""Throughput of the running system against its physical limits, measured side by side.

    python -m bench.perf.throughput  # full mode, ~5-10 min on 2 cores → docs/results/
    python -m bench.perf.throughput --quick  # CI mode: tiny sizes, well under a minute

Real services (`python -m hercs.apps.cli <role>` processes on an embedded Zenoh router), each
figure paired with a reference measured in the same run, since a noisy machine moves absolute
numbers: env steps/s of one actor against raw env stepping, learner updates/s against the same
loop in process (both in alternating slices, the system paused with SIGSTOP meanwhile), acked
inserts/s from 1–16 synthetic actors, sample latency per sampler against `ReplayCore.sample`,
and replay memory against the raw array bytes. Targets are reported, never asserted. One module
per phase (`env_steps`, `learner_updates`, `insert_rate`, `sample_latency`, `replay_memory`) on
the system `harness` starts; `report` writes docs/results/throughput.{json,md} (`--out`), whose
"How" section gives the method; results: docs/PERFORMANCE.md §1.
"""

from __future__ import annotations

import sys
import time


class BenchError(RuntimeError):
    """A phase could not measure what it should (a child died, a wait timed out)."""


def say(text: str) -> None:
    """Progress on stderr (stdout carries the markdown report)."""
    print(f"[throughput {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)
