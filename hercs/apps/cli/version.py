"""`hercs --version`: the package's version and, from a git checkout, its commit."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from hercs.apps.provenance import CHECKOUT, git_commit


def installed_version() -> str:
    """The version of the installed distribution (pyproject.toml's `version`), read from its
    metadata rather than from `hercs.__version__`: nothing in the package imports its root,
    which sits above every layer (pyproject.toml, the import-linter contract "root-on-top")."""
    try:
        return version("hercs")
    except PackageNotFoundError:  # a bare checkout on PYTHONPATH
        return "(not installed)"


def version_text(where: Path = CHECKOUT) -> str:
    """What `hercs --version` prints: the package's version, and where hercs runs from a git
    checkout, its commit (`hercs 0.1.0, commit 6c0374e`)."""
    text = f"hercs {installed_version()}"
    if not (where / ".git").exists():  # installed: site-packages is no checkout of hercs
        return text
    commit = git_commit(where)
    return text if commit == "unknown" else f"{text}, commit {commit}"
