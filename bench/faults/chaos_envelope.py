"""Does a run's success curve lie where fault-free runs of its configuration lie?
(bench.faults.chaos)

The envelope of the fault-free seeds' smoothed curves, with the check calibrated on those seeds
themselves (`leave_one_out`). Why so: docs/FAULTS.md, "The chaos soak".
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hercs.run.metrics import read_rows
from hercs.run.rundir import CONFIG, RunDir

IGNORED = ("run.name", "run.seed", "run.run_dir", "run.tensorboard", "training.epochs",
           "transport.", "security.", "launch.", "view.", "tracking.")
"""Config fields that do not change what is learnt (names, seeds, where it listens, how it
is secured and supervised, how long it runs): two runs differing only there are of one
configuration."""


def success_curve(run_dir: Path) -> list[float]:
    """`success_rate` of metrics.csv by epoch (index 0 = epoch 1; nan where an epoch has no
    row or no value; the last row of an epoch wins)."""
    rates: dict[int, float] = {}
    for row in read_rows(RunDir(run_dir).metrics):
        if row.get("epoch"):
            value = row.get("success_rate") or "nan"
            rates[int(row["epoch"])] = float(value)
    return [rates.get(e, math.nan) for e in range(1, max(rates, default=0) + 1)]


def smoothed(curve: Sequence[float], window: int) -> list[float]:
    """The trailing mean over `window` epochs (fewer at the start); nan if any is nan."""
    if window < 1:
        raise ValueError(f"window: got {window}, expected >= 1 epoch")
    return [sum(curve[max(0, i - window + 1):i + 1]) / len(curve[max(0, i - window + 1):i + 1])
            for i in range(len(curve))]


@dataclass
class EnvelopeCheck:
    """One curve against the envelope of `seeds` fault-free curves over `epochs` epochs."""

    seeds: int
    epochs: int
    window: int
    outside: list[tuple[int, float, float, float]] = field(default_factory=list)
    """(epoch, value, low, high) of every epoch whose smoothed value left the envelope."""

    @property
    def inside(self) -> bool:
        return self.epochs > 0 and not self.outside

    def describe(self) -> str:
        if self.epochs == 0:
            return "no epoch to compare"
        if not self.outside:
            return f"inside at all {self.epochs} epochs"
        worst = ", ".join(f"{e}: {v:.2f} ∉ [{lo:.2f}, {hi:.2f}]"
                          for e, v, lo, hi in self.outside[:4])
        more = f", … ({len(self.outside)} in all)" if len(self.outside) > 4 else ""
        return f"outside at {len(self.outside)} of {self.epochs} epochs ({worst}{more})"


def check(curve: Sequence[float], baselines: Sequence[Sequence[float]], *,
          window: int) -> EnvelopeCheck:
    """`curve` against the envelope of `baselines`, each smoothed by `window`, over the
    epochs every one of them has (an epoch with a nan anywhere is left out)."""
    if not baselines:
        return EnvelopeCheck(seeds=0, epochs=0, window=window)
    smooth = smoothed(curve, window)
    others = [smoothed(b, window) for b in baselines]
    length = min(len(smooth), *(len(o) for o in others))
    result = EnvelopeCheck(seeds=len(baselines), epochs=0, window=window)
    for i in range(length):
        values = [o[i] for o in others]
        if math.isnan(smooth[i]) or any(math.isnan(v) for v in values):
            continue
        result.epochs += 1
        low, high = min(values), max(values)
        if not low - 1e-9 <= smooth[i] <= high + 1e-9:
            result.outside.append((i + 1, smooth[i], low, high))
    return result


def leave_one_out(baselines: Mapping[str, Sequence[float]], *,
                  window: int) -> dict[str, EnvelopeCheck]:
    """Each fault-free seed against the envelope of the others (the check's calibration);
    empty with fewer than three seeds (an envelope of one curve is no range)."""
    if len(baselines) < 3:
        return {}
    return {name: check(curve, [c for n, c in baselines.items() if n != name], window=window)
            for name, curve in baselines.items()}


def _flat(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, Mapping):
            flat.update(_flat(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def config_differences(run_dir: Path, other: Path) -> list[str]:
    """The config fields (outside `IGNORED`) whose values differ between two runs' saved
    config.yaml, as `field: a ≠ b`; one line saying so where a file is missing."""
    configs = []
    for folder in (run_dir, other):
        path = RunDir(folder).config
        if not path.is_file():
            return [f"no {CONFIG} in {folder}"]
        configs.append(_flat(yaml.safe_load(path.read_text()) or {}))
    a, b = configs
    return [f"{key}: {a.get(key)!r} ≠ {b.get(key)!r}" for key in sorted(set(a) | set(b))
            if not key.startswith(IGNORED) and a.get(key) != b.get(key)]
