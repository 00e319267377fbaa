"""Task names that make hercs import code, and which of them this process may import.

`package.module:factory` names an environment a user's own package makes, and a gymnasium id
of the form `module:Env-v0` makes gymnasium import `module` first. Either imports code, so
hercs resolves such a name only when the user named it (`--task`, `--set task.name=`, a
`--config` file given on the command line, `task=` in Python) or said `--trust-task`: a
name read from a run folder (config.yaml, a checkpoint's embedded config) is refused, so that
a folder someone sends cannot make `hercs eval`, `hercs up --resume` or `hercs.load_policy`
import a module (docs/SECURITY.md). The trusted names travel to child processes in
`TRUST_ENV`, so that the services a launcher starts read the run's config.yaml as it did.
"""

from __future__ import annotations

import os
import re

from hercs.errors import ConfigError
from hercs.rl.task_spec import FACTORY

TRUST_ENV = "HERCS_TRUSTED_TASKS"
"""Task names this process and its children may import code for, separated by newlines; `*`
trusts any (`--trust-task`)."""

ANY = "*"

GYM_MODULE_ID = re.compile(r"([A-Za-z_][\w.]*):[\w./-]+-v\d+")
"""gymnasium's `module:EnvName-vN`: `gymnasium.make` imports `module` before it looks the id up."""


def imported_module(name: str) -> str | None:
    """The module resolving task name `name` would import, None for a name that imports
    nothing of its own (a preset, a registered gymnasium id)."""
    if FACTORY.fullmatch(name):
        return name.partition(":")[0]
    match = GYM_MODULE_ID.fullmatch(name)
    return match.group(1) if match else None


def _trusted() -> set[str]:
    return {n for n in os.environ.get(TRUST_ENV, "").split("\n") if n}


def trust_task(name: str) -> None:
    """Let this process and the processes it starts import the code `name` names (the user
    named it); `ANY` trusts every name."""
    if name == ANY or imported_module(name) is not None:
        os.environ[TRUST_ENV] = "\n".join(sorted(_trusted() | {name}))


def check_may_import(name: str, *, source: str = "task.name") -> None:
    """Raise ConfigError where `name` would import code that the user did not name."""
    module = imported_module(name)
    if module is None:
        return
    trusted = _trusted()
    if ANY in trusted or name in trusted:
        return
    raise ConfigError(
        f"{source}: {name!r} names code to import (module {module!r}), and hercs imports code "
        "only where you name it yourself, never because a file (a run's config.yaml, a "
        "checkpoint) says so: give --task " + name + " (task=" + repr(name) + " in Python), or "
        "--trust-task if you trust the folder it came from (docs/SECURITY.md)")
