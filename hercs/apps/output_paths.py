"""Where a command will write, checked before it does any work: the folder exists and can be
written, the name is not a folder, and its format is one the writer knows. A long `hercs eval
--video` or a plot over hundreds of runs must not end in a traceback at its last step."""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable, Iterable
from pathlib import Path

from hercs.errors import HercsError


class OutputPathError(HercsError):
    """An output path the command could not write: the message names the flag and the path."""


def plot_formats() -> tuple[str, ...]:
    """The file formats matplotlib can save here (png, pdf, svg, jpg, …)."""
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted(FigureCanvasBase.get_supported_filetypes()))


def check_output_file(path: str | Path, *, flag: str, formats: Iterable[str] | None = None,
                      makes_folder: bool = False) -> Path:
    """`path` as a file the command may create or replace; `formats`: the suffixes (without
    the dot) its writer takes, None for any; `makes_folder`: the writer makes a missing
    folder itself (`hercs plot -o`), so only the nearest existing one is checked. Raises
    OutputPathError naming `flag`."""
    out = Path(path)
    if formats is not None:
        allowed = tuple(formats)
        suffix = out.suffix.lstrip(".").lower()
        if suffix not in allowed:
            said = f"'{suffix}'" if suffix else "no file extension"
            raise OutputPathError(f"{flag} {path}: {said} is not a format it can write "
                                  f"(one of: {', '.join(allowed)})")
    if out.is_dir():
        raise OutputPathError(f"{flag} {path}: is a folder; give a file name")
    if makes_folder:
        check_output_folder(out.parent, flag=flag)
    else:
        _check_folder(out.parent, flag=flag, path=path)
    return out


def check_output_folder(path: str | Path, *, flag: str) -> Path:
    """`path` as a folder the command may create (with its parents) or write into."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise OutputPathError(f"{flag} {path}: is a file, not a folder")
    existing = out
    while not existing.exists():  # the nearest folder that exists must take new entries
        existing = existing.parent
    _check_folder(existing, flag=flag, path=path)
    return out


def _check_folder(folder: Path, *, flag: str, path: str | Path) -> None:
    if folder.exists() and not folder.is_dir():
        raise OutputPathError(f"{flag} {path}: {folder} is a file, not a folder")
    if not folder.is_dir():
        raise OutputPathError(f"{flag} {path}: its folder {folder} does not exist; make it "
                              "first or give another path")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputPathError(f"{flag} {path}: its folder {folder} cannot be written by this "
                              "user")


VIDEO_FORMATS: tuple[str, ...] = ("mp4", "mkv", "mov")
"""Containers the eval video's H.264 stream goes into (imageio-ffmpeg picks by the suffix)."""
Formats = Callable[[], tuple[str, ...]] | None
OUTPUT_FILES: dict[str, tuple[tuple[str, str, Formats, bool], ...]] = {
    "config": (("output", "-o", None, False),),
    "plot": (("output", "-o", plot_formats, True), ("table", "--table", None, False)),
    "view": (("save", "--save", lambda: ("rrd",), False),),
    "eval": (("video", "--video", lambda: VIDEO_FORMATS, False),
             ("rerun_save", "--rerun-save", lambda: ("rrd",), False)),
}
"""Per command: the attribute, the flag, the formats (None: any) of each file it writes, and
whether its writer makes a missing folder (the figure of `hercs plot` always did)."""


def check_outputs(args: argparse.Namespace) -> None:
    """Every output path of `args.command`, before any work (OutputPathError)."""
    for attr, flag, formats, makes_folder in OUTPUT_FILES.get(args.command, ()):
        value = getattr(args, attr, None)
        if value:
            check_output_file(value, flag=flag, formats=formats() if formats else None,
                              makes_folder=makes_folder)
    if args.command == "certs":
        check_output_folder(args.out, flag="DIR")
