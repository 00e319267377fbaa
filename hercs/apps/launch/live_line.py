"""The live line under `hercs up`'s epoch lines on a terminal: a bar of the running epoch's
cycles and its counts (hercs.apps.launch.epoch_progress.LiveStatus), redrawn in place with
rich; the lines printed meanwhile go above it. Only for a terminal: a log keeps its lines."""

from __future__ import annotations

import contextlib
from typing import IO

from rich.console import Console
from rich.live import Live
from rich.progress_bar import ProgressBar
from rich.table import Table
from rich.text import Text

from hercs.apps.launch.epoch_progress import LiveStatus

BAR_WIDTH = 24


def is_terminal(stream: IO[str]) -> bool:
    """Whether `stream` writes to a terminal (a file, a pipe or a test's buffer does not)."""
    try:
        return stream.isatty()
    except (AttributeError, OSError, ValueError):
        return False


class LiveLine:
    """One redrawn line on the terminal `out`; `say` prints a line above it (`err`'s lines
    too: the line is taken down while one is written, so the two streams never interleave
    on the screen). `close` takes it down for good."""

    def __init__(self, out: IO[str], err: IO[str]) -> None:
        self._err = err
        self._console = Console(file=out, highlight=False, soft_wrap=True)
        self._live = Live(console=self._console, auto_refresh=False, transient=True,
                          redirect_stdout=False, redirect_stderr=False)
        self._shown = False

    def show(self, status: LiveStatus) -> None:
        row = Table.grid(padding=(0, 1))
        row.add_row(ProgressBar(total=1.0, completed=status.fraction, width=BAR_WIDTH),
                    Text(status.text()))
        if not self._shown:
            self._live.start()
            self._shown = True
        self._live.update(row, refresh=True)

    def say(self, line: str, *, error: bool = False) -> None:
        if not error:
            self._console.print(Text(line))  # above the live line, which is drawn again
            return
        was_shown = self._shown
        self._take_down()
        print(line, file=self._err, flush=True)
        if was_shown:
            self._live.start(refresh=True)
            self._shown = True

    def _take_down(self) -> None:
        if self._shown:
            with contextlib.suppress(OSError, ValueError):
                self._live.stop()
            self._shown = False

    def close(self) -> None:
        self._take_down()
