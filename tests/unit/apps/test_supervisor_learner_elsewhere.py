"""`hercs up` with `launch.learner_elsewhere` (a stacked learner's runs): its supervisor ends
the run when that learner's `RunProgress` says it finished (0) or diverged (4, saying so), and
not on the word of a learner that trains on; a run with its own learner ignores the flag."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from hercs.apps.launch.run_plan import child_argv
from hercs.apps.launch.supervisor import Supervisor
from hercs.config import HercsConfig, apply_overrides
from hercs.errors import ConfigError
from hercs.net.service_shell import EXIT_DIVERGED
from hercs.net.signals import StopSignals
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb


def supervisor(tmp_path: Path, *overrides: str) -> tuple[Supervisor, io.StringIO]:
    config = apply_overrides(HercsConfig(), ["run.name=r", *overrides])
    err = io.StringIO()
    return Supervisor(config=config, run_dir=tmp_path, signals=StopSignals(),
                      command=child_argv, stop_timeout_s=1.0, ready_timeout_s=1.0,
                      out=io.StringIO(), err=err), err


def progress(**fields: object) -> bytes:
    return pb.RunProgress(schema_version=SCHEMA_VERSION, epochs=3, **fields).SerializeToString()


def test_the_learners_word_ends_the_run(tmp_path: Path) -> None:
    sup, _ = supervisor(tmp_path, "launch.learner_elsewhere=true")
    sup.on_run_progress("k", progress(epoch=1, cycle=10))
    assert sup.check_children() is None  # it trains on
    sup.on_run_progress("k", progress(epoch=3, finished=True))
    assert sup.check_children() == 0


def test_a_diverged_learner_elsewhere_stops_the_run_with_4_and_says_so(tmp_path: Path) -> None:
    sup, err = supervisor(tmp_path, "launch.learner_elsewhere=true")
    sup.on_run_progress("k", progress(epoch=2, diverged=True))
    assert sup.check_children() == EXIT_DIVERGED
    assert "says its training diverged after epoch 2" in err.getvalue()


def test_a_run_with_its_own_learner_waits_for_that_learner(tmp_path: Path) -> None:
    sup, _ = supervisor(tmp_path)
    sup.on_run_progress("k", progress(epoch=3, finished=True))
    assert sup.check_children() is None  # its own learner's exit ends it


def test_a_bad_value_is_refused_by_name() -> None:
    with pytest.raises(ConfigError, match=r"launch\.learner_elsewhere"):
        apply_overrides(HercsConfig(), ["launch.learner_elsewhere=maybe"])
