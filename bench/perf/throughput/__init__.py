"""Throughput of the running system against its physical limits, measured side by side.

    python -m bench.perf.throughput  # full mode, ~5-10 min on 2 cores → docs/results/

One module per phase on the system `harness` starts; `report` writes docs/results/throughput.md,
whose "How" section gives the method. Results: docs/PERFORMANCE.md §1."""

from __future__ import annotations

import sys
import time


class BenchError(RuntimeError):
    """A phase could not measure what it should (a child died, a wait timed out)."""


def say(text: str) -> None:
    """Progress on stderr (stdout carries the markdown report)."""
    print(f"[throughput {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)
