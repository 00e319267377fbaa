"""`make test`/`make run` install the CPU build of torch: resolving the Makefile's torch line
from scratch (pip's dry run, ignoring what is installed) picks torch+cpu and no CUDA
package. Needs the package indexes the Makefile names (or a local mirror, as here)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.integration, pytest.mark.timeout(400)]

REPO = Path(__file__).resolve().parents[2]
CUDA_PACKAGES = re.compile(r"^(nvidia-|cuda-|triton$)", re.IGNORECASE)


def makefile_default(name: str) -> str:
    match = re.search(rf"^{name} \?= (.+)$", (REPO / "Makefile").read_text(), re.MULTILINE)
    assert match, f"Makefile has no default for {name}"
    return match.group(1).strip()


def test_the_makefiles_torch_resolves_to_the_cpu_build(tmp_path: Path) -> None:
    makefile = (REPO / "Makefile").read_text()
    pin = re.search(r"install --quiet (torch==[0-9.]+) --index-url \$\(TORCH_INDEX\)", makefile)
    assert pin, "the Makefile installs a pinned torch from $(TORCH_INDEX)"
    report = tmp_path / "report.json"
    done = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--quiet",
         "--retries", "0", "--report", str(report), pin.group(1),
         "--index-url", makefile_default("TORCH_INDEX")],
        capture_output=True, text=True, timeout=360)
    assert done.returncode == 0, done.stderr[-2000:]
    installs = {item["metadata"]["name"]: item["metadata"]["version"]
                for item in json.loads(report.read_text())["install"]}
    assert installs["torch"].endswith("+cpu"), installs["torch"]
    cuda = sorted(name for name in installs if CUDA_PACKAGES.match(name))
    assert not cuda, f"the CPU install would pull {cuda}"
