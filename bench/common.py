"""What every benchmark script shares: the commit its results were measured at, how a report
is written, and starting a group of things (hosts, actors) that are all stopped however it ends."""

from __future__ import annotations

import argparse
import contextlib
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

from hercs.apps import provenance
from hercs.apps.provenance import VECTOR_EXTENSIONS, cpu_info, machine_identity
from reports import add_out_option, report_folder, write_report

__all__ = [
    "QUICK_EPOCHS",
    "REPO",
    "VECTOR_EXTENSIONS",
    "add_out_option",
    "add_run_options",
    "all_started",
    "apply_quick",
    "cpu_info",
    "git_commit",
    "machine_identity",
    "parse_run_args",
    "report_folder",
    "report_head",
    "script_parser",
    "show_report",
    "table_with_notes",
    "timed_cli",
    "write_report",
]

REPO = Path(__file__).resolve().parents[1]

T = TypeVar("T")


def table_with_notes(lines: list[str], notes: Iterable[tuple[str, str]]) -> str:
    """A fault report's markdown: its table lines, then each (row, note) as a list item naming
    its row."""
    return "\n".join([*lines, *(f"\n- {row}: {note}" for row, note in notes)]) + "\n"


def git_commit() -> str:
    """This checkout's short commit (hercs.apps.provenance.git_commit)."""
    return provenance.git_commit(REPO)


def show_report(args: argparse.Namespace, name: str, summary: Any, text: str) -> None:
    """A benchmark's report printed, then written with its summary where its `--out` and
    `--quick` say (report_folder, write_report)."""
    print(text)
    write_report(report_folder(args.out, args.quick, REPO), name, summary, text)


def report_head(module: str, title: str, summary: dict[str, Any], what: str) -> list[str]:
    """A run-level benchmark report's first lines: `# title (python -m module)`, then `date,
    commit, CPU, N cores; what` (from the summary's date, commit, machine, cores and quick)."""
    quick = ", quick mode" if summary["quick"] else ""
    return [f"# {title} (`python -m {module}`)", "",
            f"{summary['date']}, commit `{summary['commit']}`, {summary['machine']['cpu']}, "
            f"{summary['cores']} cores; {what}{quick}.", ""]


QUICK_EPOCHS = "training.cycles_per_epoch=5"
"""The override a run-level benchmark's quick mode adds: epochs of 5 cycles."""


def script_parser(module: str, doc: str | None) -> argparse.ArgumentParser:
    """The parser of `python -m module`, whose help shows `doc` (the script's docstring) with
    its line breaks."""
    return argparse.ArgumentParser(prog=f"python -m {module}", description=doc,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def add_run_options(parser: argparse.ArgumentParser, name: str) -> None:
    """The options of a benchmark made of whole `hercs` runs: `--set` (each run's config
    overrides), `--quick` and `--out`."""
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a config override for every run (repeatable)")
    parser.add_argument("--quick", action="store_true",
                        help=f"CI: a few short runs ({QUICK_EPOCHS})")
    add_out_option(parser, name)


def parse_run_args(parser: argparse.ArgumentParser, argv: Sequence[str] | None, name: str,
                   problem: Callable[[argparse.Namespace], str | None],
                   **small: Any) -> argparse.Namespace:
    """A run-level benchmark's arguments: `parser` (its own options) with `--set`, `--quick`
    and `--out` added (add_run_options) parses `argv`; `problem(args)`, where not None, is a
    usage error (checked on the values given, before `--quick` replaces them); then the quick
    mode's small values (apply_quick)."""
    add_run_options(parser, name)
    args = parser.parse_args(argv)
    if (why := problem(args)) is not None:
        parser.error(why)
    apply_quick(args, **small)
    return args


def apply_quick(args: argparse.Namespace, **small: Any) -> None:
    """With `--quick`: the benchmark's small values (`task="reach"`, `epochs=2`, …) over its
    arguments, and epochs of 5 cycles for every run."""
    if args.quick:
        for name, value in small.items():
            setattr(args, name, value)
        args.set = [*args.set, QUICK_EPOCHS]


def timed_cli(bench: str, args: Sequence[str]) -> float:
    """Wall seconds of `python -m hercs.apps.cli ARGS` run in this checkout; the benchmark
    exits, naming the command and showing its output's end, if it fails."""
    command = [sys.executable, "-m", "hercs.apps.cli", *args]
    started = time.monotonic()
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
    wall = time.monotonic() - started
    if done.returncode != 0:
        sys.exit(f"{bench}: `hercs {' '.join(args)}` failed ({done.returncode}):\n"
                 f"{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return wall


@contextlib.contextmanager
def all_started(items: Sequence[T], start: Callable[[T], object],
                stop: Callable[[T], object]) -> Iterator[Sequence[T]]:
    """`start` each item in turn, then the block; `stop` every item however the block or a
    start ends, those never started included (so `stop` must cope with them)."""
    try:
        for item in items:
            start(item)
        yield items
    finally:
        for item in items:
            stop(item)
