"""bench/perf/gpu_check.sh, the GPU checks of a lent machine: valid shell, and every test file and
benchmark module it names exists (it runs only on a CUDA machine, so rot would show there
first, where time is scarce)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
SCRIPT = REPO / "bench" / "perf" / "gpu_check.sh"


def test_the_script_parses() -> None:
    done = subprocess.run(["bash", "-n", str(SCRIPT)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_everything_it_runs_exists() -> None:
    text = SCRIPT.read_text()
    tests = re.findall(r"tests/[\w/]+\.py", text)
    modules = re.findall(r"-m (bench\.[\w.]+)", text)
    assert len(tests) >= 3 and sorted(set(modules)) == ["bench.perf.learner_cuda",
                                                        "bench.perf.learner_feed"]
    missing = [t for t in tests if not (REPO / t).is_file()]
    missing += [m for m in modules if not (REPO / (m.replace(".", "/") + ".py")).is_file()]
    assert missing == []
