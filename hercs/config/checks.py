"""The checks every config section's `__post_init__` uses; a failed one raises `ConfigError`
naming the field, the value and what it must be."""

from __future__ import annotations

from hercs.errors import ConfigError


def _check(cond: bool, where: str, value: object, must: str) -> None:
    if not cond:
        raise ConfigError(f"{where}: got {value!r}, must {must}")


def _positive(where: str, value: float) -> None:
    _check(value > 0, where, value, "be > 0")


def _unit_interval(where: str, value: float, *, closed: bool = True) -> None:
    ok = 0.0 <= value <= 1.0 if closed else 0.0 < value < 1.0
    _check(ok, where, value, "lie in [0, 1]" if closed else "lie in (0, 1)")
