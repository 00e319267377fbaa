"""How every generated table and report prints a number, so that one value prints the same
in each: the float the report computed, correctly rounded to a fixed number of places
(Python's own format; a tie goes the way the float's binary value lies).

One value is one float here: every report takes a run's numbers from the same code
(hercs/apps/plots/curves.py), so pick-v1-her-cs-s4's 10-epoch mean at epoch 100, .685 in
decimal and 0.6849999999999999 as computed, prints .68 in claims.md and everywhere else, and
prose that quotes it should too. Test success sits on a 1/20 grid, so such ties are common;
docs/DESIGN.md §5 prints the authors' numbers by the same rule (.975 → .97, .985 → .98).
"""

from __future__ import annotations

import math

DASH = "–"
"""What a missing value (None, NaN) prints as."""


def fixed(value: float, places: int) -> str:
    """`value` to `places` decimals ("-0.00" prints as "0.00")."""
    text = f"{value:.{places}f}"
    return text[1:] if text.startswith("-") and not text.strip("-0.") else text


def rate(value: float | None) -> str:
    """A rate or probability to 2 places without the leading zero: .68, -.10, 1.00; DASH for
    None or NaN."""
    if value is None or math.isnan(value):
        return DASH
    return _no_leading_zero(fixed(value, 2))


def signed_rate(value: float) -> str:
    """A difference of rates with its sign: +.23, -.10, .00."""
    text = rate(value)
    return text if text.startswith("-") or text == ".00" else f"+{text}"


def epoch(value: float) -> str:
    """An epoch or a mean of epochs to 1 place: 77.7."""
    return fixed(value, 1)


def p_value(value: float) -> str:
    """A p-value to 3 places without the leading zero (.048), 1.00 where it rounds to 1."""
    text = fixed(value, 3)
    return "1.00" if text == "1.000" else _no_leading_zero(text)


def _no_leading_zero(text: str) -> str:
    """"0.68" → ".68", "-0.10" → "-.10"; "1.00" as it is."""
    sign, digits = ("-", text[1:]) if text.startswith("-") else ("", text)
    return sign + (digits[1:] if digits.startswith("0.") else digits)


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def power_of_ten(value: float) -> str:
    """A small or large setting as a reader writes it: 1e-3 → "10⁻³", 2.5e-4 → "2.5 × 10⁻⁴";
    a value of magnitude 0.1 to 100, zero or not finite as Python's `g` (0.5, 40, 0)."""
    if value == 0 or not math.isfinite(value) or 0.1 <= abs(value) < 100:
        return f"{value:g}"
    mantissa, exponent = f"{value:e}".split("e")
    power = "10" + str(int(exponent)).translate(_SUPERSCRIPT)
    digits = f"{float(mantissa):g}"
    return power if digits == "1" else ("−" + power if digits == "-1"
                                        else f"{digits} × {power}")
