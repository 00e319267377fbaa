"""Suite-wide settings: error replies must name a reason `hercs.reasons.Reason` knows (a new
reason without a disposition fails a test instead of silently meaning "retry"); every service
a test starts inherits it. And Ctrl-C means what it means in a terminal, however the suite was
started."""

import os
import signal
from pathlib import Path
from typing import Any

import pytest

os.environ["HERCS_STRICT_REASONS"] = "1"

# A shell without job control starts a background command (`make test &`, `nohup … &`) with
# SIGINT ignored, and an ignored signal stays ignored through exec: every command a test starts
# would then shrug off the Ctrl-C the test sends it ("stopped with Ctrl-C" tests hang until
# their timeout). A handler, unlike an ignore, resets to the default at exec, so installing
# Python's own restores SIGINT for this process and all it starts.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def trusted_test_envs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests that resolve tests/goal_envs.py's factories in-process name them as a user's
    `--task` does (hercs.rl.code_names)."""
    from hercs.rl.code_names import ANY, TRUST_ENV

    monkeypatch.setenv(TRUST_ENV, ANY)


def _work_unit(nodeid: str) -> str:
    """What one worker runs whole, in its order: the test's package (a folder with __init__.py,
    as tests/fault/fuzz/, whose modules share one package fixture and run in their numbered
    order), else its file (whose module fixtures, often a whole run, are then made once)."""
    path = nodeid.split("::", 1)[0]
    folder = Path(path).parent
    return str(folder) if (Path(__file__).parents[1] / folder / "__init__.py").exists() else path


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """`make test`'s workers (pytest-xdist, `--dist loadfile`) take whole work units
    (`_work_unit`): xdist's own loadfile would split a package over workers."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling  # type: ignore[import-untyped]

    class FileOrPackageScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _work_unit(nodeid)

    return FileOrPackageScheduling(config, log)
