"""Building the config tree's dataclasses from plain data (YAML, `--set` values): unknown keys
and wrong types are refused with the field's dotted path, YAML 1.1's yes/no/on/off are not
booleans, and keys that earlier versions saved and this one retired are ignored with a log
line, so old runs stay readable.
"""

from __future__ import annotations

import dataclasses
import difflib
import logging
import math
import re
import typing
from typing import Any

import yaml

from hercs.config.limits import EXACT_COUNT
from hercs.errors import ConfigError

log = logging.getLogger("hercs.config")

RETIRED_KEYS: dict[str, str] = {
    "cluster.failure_threshold": "an episode fails when it does not succeed by the task's own "
                                 "rule (TaskSpec.is_success)",
    "run.tensorboard": "TensorBoard is a tracker now: tracking.backends=[tensorboard] "
                       "(hercs up --track tensorboard)",
}
"""Keys that configs saved by earlier versions hold and this version ignores (with a log line),
so that old runs stay readable; any other unknown key is refused."""


def _build(cls: type, data: Any, where: str) -> Any:
    """Build dataclass `cls` from a mapping, refusing unknown keys and wrong types."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where or 'config'}: got {data!r}, must be a mapping")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for key in [k for k in data if f"{where}.{k}" in RETIRED_KEYS]:
        log.info("config: ignoring %s.%s (%s)", where, key, RETIRED_KEYS[f"{where}.{key}"])
        data = {k: v for k, v in data.items() if k != key}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"{where or 'config'}: unknown key(s) {unknown}; known: {sorted(names)}"
        )
    kwargs = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else key
        kwargs[key] = _coerce(hints[key], value, path)
    return cls(**kwargs)


def _coerce(hint: Any, value: Any, where: str) -> Any:
    args = typing.get_args(hint)
    if type(None) in args:  # `float | None`: null, or a value of the other type
        (other,) = [a for a in args if a is not type(None)]
        return None if value is None else _coerce(other, value, where)
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return _build(hint, value, where)
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: got {value!r}, must be true or false"
                          + (" (yes, no, on and off are not taken as booleans)"
                             if str(value).lower() in YAML11_BOOLS else ""))
    if hint is int:
        if isinstance(value, bool):
            raise ConfigError(f"{where}: got {value!r}, must be an integer")
        if isinstance(value, str):
            value = _parse_number(value, where)
        if isinstance(value, float) and value.is_integer():
            if abs(value) > EXACT_COUNT:  # a float there is not one integer
                raise ConfigError(
                    f"{where}: got {value!r}, must be an integer: a float past 2**53 stands "
                    "for many integers, not one (write the integer's digits; the field's "
                    "upper bound is checked next)")
            return int(value)
        if isinstance(value, int):
            return value
        raise ConfigError(f"{where}: got {value!r}, must be an integer")
    if hint is float:
        if isinstance(value, bool):
            raise ConfigError(f"{where}: got {value!r}, must be a number")
        given = value
        if isinstance(value, str):
            value = _parse_number(value, where)
        if isinstance(value, int | float):
            try:
                number = float(value)
            except OverflowError:  # an integer beyond any float
                number = math.inf
            if not math.isfinite(number):  # "1e400" too: float() makes it inf
                raise ConfigError(f"{where}: got {given!r}, must be a finite number")
            return number
        raise ConfigError(f"{where}: got {value!r}, must be a number")
    if hint is str:
        if isinstance(value, str):
            return value
        raise ConfigError(f"{where}: got {value!r}, must be a string")
    if typing.get_origin(hint) is list:
        if isinstance(value, str):
            value = [v for v in value.split(",") if v]
        if not isinstance(value, list):
            raise ConfigError(f"{where}: got {value!r}, must be a list")
        (item,) = typing.get_args(hint)
        return [_coerce(item, v, f"{where}[{i}]") for i, v in enumerate(value)]
    raise ConfigError(f"{where}: unsupported config type {hint!r}")  # pragma: no cover


YAML11_BOOLS = frozenset({"yes", "no", "on", "off"})
"""Words PyYAML's YAML 1.1 resolver reads as booleans; `StrictBoolLoader` keeps them strings."""


class StrictBoolLoader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2's booleans: only true and false (any case) are
    booleans; yes, no, on and off stay strings, which a boolean field then refuses."""


StrictBoolLoader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
StrictBoolLoader.add_implicit_resolver(
    "tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
    list("tTfF"))


def _did_you_mean(name: str, known: typing.Iterable[str], prefix: str = "") -> str:
    """' did you mean 'x.y'?' for the closest known name, or '' if none is close."""
    close = difflib.get_close_matches(name, list(known), n=1)
    return f" did you mean {prefix + close[0]!r}?" if close else ""


def _parse_number(text: str, where: str) -> int | float:
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"{where}: got {text!r}, must be a number") from None
