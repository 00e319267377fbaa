"""Where a result came from: the hercs commit that made it and the machine it ran on (one
seed gives other numbers on another CPU: docs/DESIGN.md §10). `hercs sweep` records both
with every finished run; the benchmarks with their figures."""

from __future__ import annotations

import subprocess
from pathlib import Path

CHECKOUT = Path(__file__).resolve().parents[2]
"""The folder holding the `hercs` package: a git checkout, or site-packages."""

VECTOR_EXTENSIONS = ("avx2", "avx512f", "avx512_bf16", "amx_bf16")
"""The CPU extensions that decide which matrix kernels run, and how fast bf16 is."""


def git_commit(where: Path = CHECKOUT) -> str:
    """The short commit of the checkout at `where`, marked when tracked files have
    uncommitted changes (the figures then belong to no commit); "unknown" outside one."""
    try:
        sha = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=where, check=True,
                             capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=where, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return sha + (" (with uncommitted changes)" if dirty else "")




def cpu_info() -> dict[str, str]:
    """The first CPU's /proc/cpuinfo fields (`model name`, `cpu family`, `model`, `flags`, …);
    empty where there is none."""
    fields: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, sep, value = line.partition(":")
            key = key.strip()
            if sep and key not in fields:
                fields[key] = value.strip()
    except OSError:
        pass
    return fields


def machine_identity() -> dict[str, str]:
    """Which machine a result came from, as far as it can change the numbers: the CPU (model
    name, family/model, the widest vector extensions, which decide the kernels MKL and oneDNN
    pick) and the boot (two results with one boot id come from one machine instance; a cloud
    machine of the same CPU model may still differ)."""
    fields = cpu_info()
    flags = set(fields.get("flags", "").split())
    wide = [f for f in VECTOR_EXTENSIONS if f in flags]
    cpu = (f"{fields.get('model name', 'unknown CPU')} (family {fields.get('cpu family', '?')}"
           f" model {fields.get('model', '?')}; {' '.join(wide) or 'no AVX2'})")
    try:
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()[:8]
    except OSError:
        boot = "unknown"
    return {"cpu": cpu, "boot_id": boot}
