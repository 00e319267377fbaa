"""hercs.reasons: one vocabulary of error-reply reasons, each with what a client does."""

from __future__ import annotations

import pytest

from hercs.reasons import Disposition, Reason, UnknownReason, disposition

EXPECTED = {
    Disposition.DROP: {"undecodable", "oversized", "schema_version", "unknown_run",
                       "wrong_task", "missing_field", "bad_array", "bad_dtype", "bad_shape",
                       "bad_length", "non_finite", "bad_value", "implausible", "unknown_episode"},
    Disposition.SUPERSEDED: {"stale_policy", "future_policy", "cycle_full"},
    Disposition.RETRY: {"expired", "log_failed", "unavailable", "internal", "transport",
                        "actor_queue_full"},
}


def test_every_reason_has_the_disposition_its_clients_rely_on() -> None:
    got = {d: {r.value for r in Reason if r.disposition is d} for d in Disposition}
    assert got == EXPECTED
    assert disposition("stale_policy") is Disposition.SUPERSEDED
    assert f"{Reason.BAD_SHAPE}" == "bad_shape" and Reason.BAD_SHAPE == "bad_shape"


def test_an_unknown_reason_is_an_error_in_strict_mode_and_a_retry_otherwise(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HERCS_STRICT_REASONS", "1")
    with pytest.raises(UnknownReason, match=r"'brand_new' is not in hercs\.reasons\.Reason"):
        disposition("brand_new")
    monkeypatch.delenv("HERCS_STRICT_REASONS")
    assert disposition("brand_new") is Disposition.RETRY
