"""Hand-made run folders for the tests of `hercs plot` (the `run_dirs` fixture of conftest.py
writes CURVES)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from hercs.run.rundir import RunDir

# Hand-made curves. her: seed 1 succeeds from epoch 5, seed 2 from epoch 7 (15 epochs each).
# her-cs: seeds of different lengths (8 and 6 epochs) -> aggregated over the 6 common epochs.
CURVES: dict[tuple[str, int], list[float]] = {
    ("her", 1): [0.0] * 4 + [1.0] * 11,
    ("her", 2): [0.0] * 6 + [1.0] * 9,
    ("her-cs", 1): [0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.0, 1.0],
    ("her-cs", 2): [0.0, 0.0, 0.2, 0.4, 0.6, 0.8],
}


def _write_run(root: Path, method: str, seed: int, success: list[float],
               task: str = "push") -> Path:
    run = root / f"{task}-{method}-s{seed}"
    run.mkdir()
    RunDir(run).config.write_text(yaml.safe_dump(
        {"run": {"method": method, "seed": seed, "name": run.name}, "task": {"name": task}}))
    lines = ["epoch,env_steps,success_rate,wall_s"]
    lines += [f"{e},{e * 10000},{s},{e * 1.5}" for e, s in enumerate(success, start=1)]
    RunDir(run).metrics.write_text("\n".join(lines) + "\n")
    return run

def _write_variant_run(root: Path, method: str, seed: int, success: list[float], *,
                       schedule: str = "async", precision: str = "fp32") -> Path:
    run = _write_run(root, f"{method}-{schedule}-{precision}", seed, success)
    config = yaml.safe_load(RunDir(run).config.read_text())
    config["run"]["method"] = method
    config["training"] = {"schedule": schedule}
    config["learner"] = {"precision": precision}
    RunDir(run).config.write_text(yaml.safe_dump(config))
    return run


def _write_lockstep_run(root: Path, method: str, seed: int, success: list[float]) -> Path:
    return _write_variant_run(root, method, seed, success, schedule="lockstep")


def line_look(line: Any) -> tuple[str, tuple[Any, ...], str]:
    """A drawn matplotlib line's (colour, dash pattern, marker): what tells it from the others.
    matplotlib keeps the pattern of a custom dash only as `_unscaled_dash_pattern` (offset,
    on-off sequence; None for solid); a named style reads as its name."""
    pattern = getattr(line, "_unscaled_dash_pattern", None)
    dashes = (pattern[0], tuple(pattern[1])) if pattern and pattern[1] else (line.get_linestyle(),)
    return (str(line.get_color()), dashes, str(line.get_marker()))
