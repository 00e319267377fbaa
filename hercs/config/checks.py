"""The checks every config section's `__post_init__` uses; a failed one raises `ConfigError`
naming the field, the value and what it must be."""

from __future__ import annotations

import dataclasses
import math

from hercs.errors import ConfigError


def _check(cond: bool, where: str, value: object, must: str) -> None:
    if not cond:
        raise ConfigError(f"{where}: got {value!r}, must {must}")


def _positive(where: str, value: float) -> None:
    _check(value > 0, where, value, "be > 0")


def _unit_interval(where: str, value: float, *, closed: bool = True) -> None:
    ok = 0.0 <= value <= 1.0 if closed else 0.0 < value < 1.0
    _check(ok, where, value, "lie in [0, 1]" if closed else "lie in (0, 1)")


def _finite_numbers(config: object, where: str = "") -> None:
    """Every float of dataclass `config`, and of the dataclasses it holds, is a finite number.

    One walk for the whole tree instead of a check per field: NaN fails every comparison, and
    inf passes every lower bound (`lr > 0`), so a field without an upper bound would otherwise
    take inf into a run (an infinite learning rate made the first update's weights
    non-finite, and the run stood still)."""
    for item in dataclasses.fields(config):  # type: ignore[arg-type]
        value = getattr(config, item.name)
        path = f"{where}.{item.name}" if where else item.name
        if dataclasses.is_dataclass(value):
            _finite_numbers(value, path)
        elif isinstance(value, float):
            _check(math.isfinite(value), path, value, "be a finite number")
