"""hercs/apps/plots/numbers.py: the one rule every generated table and report prints by."""

from __future__ import annotations

import math

import pytest

from hercs.apps.plots import numbers


@pytest.mark.parametrize(("value", "text"), [
    (0.6849999999999999, ".68"),  # pick-v1-her-cs-s4's 10-epoch mean at 100 as computed
    (0.975, ".97"),  # docs/DESIGN.md §5: the authors' FetchPush HER-EBP at 50
    (0.985, ".98"),  # and their PickAndPlace HER-CS at 100
    (0.72501, ".73"),
    (1.0, "1.00"),
    (0.9951, "1.00"),
    (0.0, ".00"),
    (-0.004, ".00"),  # no "-.00"
    (-0.1, "-.10"),
    (-1.25, "-1.25"),
    (None, "–"),
    (math.nan, "–"),
], ids=["float-tie-below", "design-5-push", "design-5-pick", "plain", "one", "to-one", "zero",
        "negative-zero", "negative", "below-minus-one", "none", "nan"])
def test_rate(value: float | None, text: str) -> None:
    assert numbers.rate(value) == text


def test_a_decimal_tie_prints_as_the_float_that_holds_it_lies() -> None:
    """The rule rounds the float a report computed, not its decimal: the same .685 summed in
    two orders is two floats, one each side of the tie. Every report computes a run's numbers
    with hercs/apps/plots/curves.py, so within them one run's value is one float."""
    assert numbers.rate(0.6849999999999999) == ".68"
    assert numbers.rate(0.685) == ".69"  # 0.685 as a literal: 0.68500000000000005…


@pytest.mark.parametrize(("value", "text"), [
    (0.23, "+.23"), (-0.1, "-.10"), (0.0, ".00"), (1.05, "+1.05")],
    ids=["positive", "negative", "zero", "above-one"])
def test_signed_rate(value: float, text: str) -> None:
    assert numbers.signed_rate(value) == text


@pytest.mark.parametrize(("value", "text"), [
    (0.0476, ".048"), (0.99951, "1.00"), (0.1, ".100"), (0.0, ".000")],
    ids=["small", "rounds-to-one", "trailing-zeros", "zero"])
def test_p_value(value: float, text: str) -> None:
    assert numbers.p_value(value) == text


def test_epoch_is_one_place() -> None:
    assert [numbers.epoch(v) for v in (77.66666, 43.26, 50.0, -0.01)] == [
        "77.7", "43.3", "50.0", "0.0"]
