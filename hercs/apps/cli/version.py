"""`hercs --version`: the package's version and, from a git checkout, its commit."""

from __future__ import annotations

from pathlib import Path

from hercs.apps.provenance import CHECKOUT, git_commit


def version_text(where: Path = CHECKOUT) -> str:
    """What `hercs --version` prints: the package's version, and where hercs runs from a git
    checkout, its commit (`hercs 0.1.0, commit 6c0374e`)."""
    from hercs import __version__

    text = f"hercs {__version__}"
    if not (where / ".git").exists():  # installed: site-packages is no checkout of hercs
        return text
    commit = git_commit(where)
    return text if commit == "unknown" else f"{text}, commit {commit}"
