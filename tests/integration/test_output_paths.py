"""Every command that writes a file or folder checks where, before any work: a missing folder,
a file where a folder goes, or a format its writer does not take is refused with exit 2 and a
message naming the flag, never a traceback after the work (issue: `hercs eval --video` ran
every episode, then ffmpeg's BrokenPipeError)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
RUN = REPO / "docs" / "results" / "runs" / "push-her-s1"  # committed, with its best.pt
DEMO = REPO / "docs" / "demo" / "push-her-cs"  # committed episode log


def cases(tmp: Path) -> list[tuple[str, list[str], str]]:
    missing = tmp / "no-such-folder"
    a_file = tmp / "a-file"
    a_file.write_text("")
    return [
        ("plot-folder", ["plot", str(RUN), "-o", str(a_file / "x.png")], "-o"),
        ("plot-format", ["plot", str(RUN), "-o", str(tmp / "x.jpgg")], "'jpgg'"),
        ("plot-table", ["plot", str(RUN), "-o", str(tmp / "x.png"),
                        "--table", str(missing / "t.md")], "--table"),
        ("eval-video-folder", ["eval", str(RUN), "--video", str(missing / "x.mp4")],
         "--video"),
        ("eval-video-format", ["eval", str(RUN), "--video", str(tmp / "x.gifv")], "'gifv'"),
        ("eval-rerun", ["eval", str(RUN), "--rerun-save", str(missing / "x.rrd")],
         "--rerun-save"),
        ("view-folder", ["view", str(DEMO), "--save", str(missing / "x.rrd")], "--save"),
        ("view-format", ["view", str(DEMO), "--save", str(tmp / "x.rr")], "'rr'"),
        ("config", ["config", "-o", str(missing / "c.yaml")], "-o"),
        ("certs", ["certs", str(a_file / "certs")], "DIR"),
        ("sweep-out", ["sweep", "--quick", "--dry-run", "--out", str(a_file)], "--out"),
        ("sweep-run-dir", ["sweep", "--quick", "--dry-run", "--run-dir", str(a_file)],
         "--run-dir"),
        ("sweep-report", ["sweep", "report", str(tmp), "--out", str(a_file)], "report --out"),
    ]


NAMES = ("plot-folder", "plot-format", "plot-table", "eval-video-folder", "eval-video-format",
         "eval-rerun", "view-folder", "view-format", "config", "certs", "sweep-out",
         "sweep-run-dir", "sweep-report")


@pytest.mark.parametrize("case", NAMES)
def test_a_bad_output_path_is_refused_before_any_work(tmp_path: Path, case: str) -> None:
    name, argv, named = next(c for c in cases(tmp_path) if c[0] == case)
    got = subprocess.run([sys.executable, "-m", "hercs.apps.cli", *argv], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert got.returncode == 2, (name, got.stdout[-1000:], got.stderr[-2000:])
    assert "Traceback" not in got.stderr, got.stderr[-2000:]
    assert named in got.stderr, got.stderr
    leftovers = {p.name for p in tmp_path.iterdir()} - {"a-file"}
    assert not leftovers, f"{name}: wrote {leftovers} though refused"
