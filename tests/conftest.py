"""Suite-wide settings: error replies must name a reason `hercs.reasons.Reason` knows (a new
reason without a disposition fails a test instead of silently meaning "retry"); every service
a test starts inherits it. And Ctrl-C means what it means in a terminal, however the suite was
started."""

import os
import signal

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
