"""bench.faults.stranded_gets' quick mode: real router, real Zenoh sessions, real SIGKILLs of a
stand-in replay holding a request. Each kill ends in exactly one outcome; asking again, as
the learner does, leaves no request stranded (a stranded get, ~4 % of kills under load, is
what the full run measures: docs/results/faults.md)."""

from __future__ import annotations

import pytest

from bench.faults.stranded_gets import main, measure, summary

pytestmark = pytest.mark.integration


def test_every_kill_ends_in_one_outcome_and_asking_again_strands_nothing() -> None:
    results = measure(3, timeout_s=20.0, ask_again_s=2.0, echo=False)
    counts = summary(results)
    assert counts["kills"] == 3 == len(results)
    assert counts["stranded"] == 0, results
    assert counts["answered"] + counts["no_queryable"] == 3, results
    assert all(r.requests >= 1 for r in results)
    # an answer never waits for the whole timeout: at most one ask-again period per lost get
    assert all(r.after_kill_s < 20.0 for r in results if r.outcome == "answered"), results


@pytest.mark.parametrize("argv", [["--kills", "0"], ["--ask-again", "40", "--timeout", "30"]])
def test_bad_flags_are_refused_naming_them(argv: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2 and "--ask-again in (0, --timeout)" in capsys.readouterr().err
