"""What a run ran with where its saved config.yaml lacks a field: a field added after runs had
saved their configs without it says, in its `UNSAVED` metadata (and its docstring), the value
those runs used, which readers of old runs' files (`hercs plot`'s series keys) take for it."""

from __future__ import annotations

import dataclasses
from typing import Any

UNSAVED = "unsaved"
"""The metadata key of a config field: the value a saved config without the field ran with."""


def unsaved_default(section: type, name: str) -> Any:
    """Config section `section`'s field `name` as a saved config that lacks it ran: its
    `UNSAVED` metadata where it has one, else its default."""
    found = {f.name: f for f in dataclasses.fields(section)}[name]
    return found.metadata.get(UNSAVED, found.default)
