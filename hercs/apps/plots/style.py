"""How each series looks, in every figure hercs draws (`hercs plot`, Fig. 2, a sweep's report):
one table. A method has one colour everywhere (METHOD_COLORS); what a series changes from
hercs' defaults has a line style (PREFERRED_DASH; the authors' published curves alone are
dashed); the simulator it ran on has a marker (MARKERS). In one figure no two series share a
colour and a line style: one whose preferred style its colour already has takes the next free
one (`assign_styles`). Markers come every few epochs, staggered between a panel's series
(`mark_every`), so that curves which coincide still show each one's colour.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from hercs.apps.plots.series import changes, is_env_version, method_rank
from hercs.rl.methods import METHODS

PALETTE: tuple[str, ...] = ("#0072B2", "#D55E00", "#009E73", "#E69F00",
                            "#56B4E9", "#CC79A7", "#000000", "#F0E442")
"""Okabe & Ito's colour-blind-safe colours: blue, vermillion, bluish green, orange, sky blue,
reddish purple, black and yellow."""
METHOD_COLORS: dict[str, str] = dict(zip(METHODS, PALETTE, strict=False))
"""Each method of hercs.rl.methods its own colour, the same in every figure: the palette's,
in the table's order."""
OTHER_COLORS: tuple[str, ...] = PALETTE[len(METHOD_COLORS):] or PALETTE
"""Methods not in the table (a user's), in the order they rank: the colours the table's leave,
then again."""


@dataclass(frozen=True)
class Dash:
    """A line style: its name in words (for legends and captions) and matplotlib's pattern."""

    words: str
    pattern: str | tuple[float, tuple[float, ...]]


SOLID = Dash("solid", "-")
DASHED = Dash("dashed", (0, (5.0, 2.5)))
DOTTED = Dash("dotted", (0, (1.0, 1.6)))
DASH_DOT = Dash("dash-dot", (0, (6.0, 2.0, 1.5, 2.0)))
DASH_DOT_DOT = Dash("dash-dot-dot", (0, (6.0, 1.8, 1.5, 1.8, 1.5, 1.8)))
LONG_DASH = Dash("long dashes", (0, (11.0, 3.0)))
SHORT_DASH = Dash("short dashes", (0, (2.0, 1.5)))
DASH_DASH_DOT = Dash("dash-dash-dot", (0, (5.0, 1.8, 5.0, 1.8, 1.5, 1.8)))
LONG_DASH_DOT = Dash("long dash-dot", (0, (11.0, 2.5, 1.5, 2.5)))
LOOSE_DASH = Dash("loose dashes", (0, (4.0, 5.0)))
LOOSE_DOT = Dash("loose dots", (0, (1.0, 4.0)))

PUBLISHED = DASHED
"""The authors' published curves' style, and theirs alone."""
PREFERRED_DASH: dict[str, Dash] = {
    "defaults": SOLID,  # ours with hercs' defaults
    "simulator": DOTTED,  # ours with the defaults on another simulator (v1, a torquescale)
    "schedule": DASH_DOT,  # lockstep
    "precision": DASH_DOT_DOT,  # a bf16 or TF32 learner
    "lag": LONG_DASH,  # policy-lag settings other than the defaults
    "epsilon": SHORT_DASH,  # EBP's energy floor other than today's
    "share": DASH_DASH_DOT,  # another cluster share rule
    "code": LONG_DASH_DOT,  # runs another program made
    "variant": LOOSE_DASH,  # a caller's own variant
}
"""Each kind of change's line style: a series takes the style of the first change its key
names (key order: schedule, precision, variant, lag, ε, share rule, simulator)."""
FREE_DASHES: tuple[Dash, ...] = (SOLID, DOTTED, DASH_DOT, DASH_DOT_DOT, LONG_DASH, SHORT_DASH,
                                 DASH_DASH_DOT, LONG_DASH_DOT, LOOSE_DASH, LOOSE_DOT)
"""Where a preferred style is taken, the first of these free for the colour: eleven series of
one method in a figure before a (colour, style) pair repeats."""


@dataclass(frozen=True)
class Marker:
    words: str
    symbol: str


MARKERS: dict[str, Marker] = {
    "v4": Marker("circle", "o"), "v1": Marker("square", "s"), "ts": Marker("triangle", "^"),
}
"""The simulator's marker: our default (gymnasium-robotics Fetch*-v4), the authors' (gym
Fetch*-v1, which their published curves are on too: hollow there), v4 with another weld
torquescale."""
SIMULATOR_WORDS: dict[str, str] = {
    "v4": "our default simulator (v4)", "v1": "the authors' simulator (v1)",
    "ts": "v4 with another weld torquescale",
}
MARKS_PER_SERIES = 20
"""About how many markers a series spanning the panel carries."""


@dataclass(frozen=True)
class Line:
    """One drawn series: a series key of ours, or the authors' published curve of a method."""

    key: str
    published: bool = False


@dataclass(frozen=True)
class LineStyle:
    color: str
    dash: Dash
    marker: Marker
    simulator: str  # a MARKERS key
    hollow: bool  # the authors' published curves: hollow markers


def mark_every(points: int, span: int, slot: int, slots: int) -> tuple[int, int]:
    """matplotlib's markevery (start, step) for the `slot`-th of a panel's `slots` lines, of
    `points` points in a panel `span` epochs wide: a marker about every span /
    MARKS_PER_SERIES epochs and never fewer epochs apart than there are lines, each line's
    first one shifted by its slot, so that no two lines' markers fall on one epoch."""
    step = max(slots, round(span / MARKS_PER_SERIES), 1)
    start = (slot * step) // max(1, slots)
    return (min(start, max(0, points - 1)), step)


def kind_of_change(key: str) -> str:
    """Which PREFERRED_DASH entry a series key of ours takes."""
    changed, env = changes(key)
    if not changed:
        return "simulator" if env else "defaults"
    first = changed[0]
    if first in ("lockstep",):
        return "schedule"
    if first in ("bf16", "tf32", "fp16"):
        return "precision"
    for prefix, kind in (("lag=", "lag"), ("eps", "epsilon"), ("share=", "share")):
        if first.startswith(prefix):
            return kind
    return "code" if first == "authors-code" else "variant"


def simulator_of(line: Line) -> str:
    if line.published:
        return "v1"
    env = [v for v in line.key.split("/")[1:] if is_env_version(v)]
    return "v1" if "v1" in env else "ts" if env else "v4"


def assign_styles(lines: Iterable[Line]) -> dict[Line, LineStyle]:
    """Every line of one figure its style: its method's colour; the authors' published curves
    dashed; ours the style of their change (`kind_of_change`), or where that (colour, style)
    is taken the first free one, the series with fewest changes served first; the
    simulator's marker. The same lines get the same styles, in whatever order they come."""
    unique = set(lines)
    methods = sorted({line.key.split("/")[0] for line in unique},
                     key=method_rank)
    others = [m for m in methods if m not in METHOD_COLORS]
    color_of = {m: METHOD_COLORS.get(m) or OTHER_COLORS[others.index(m) % len(OTHER_COLORS)]
                for m in methods}

    def order(line: Line) -> tuple[int, int, tuple[int, str]]:
        changed, env = changes(line.key)
        return (not line.published, len(changed) + len(env), method_rank(line.key))

    taken: dict[str, set[Dash]] = {}
    styles = {}
    for line in sorted(unique, key=order):
        color = color_of[line.key.split("/")[0]]
        used = taken.setdefault(color, set())
        dash = PUBLISHED if line.published else PREFERRED_DASH[kind_of_change(line.key)]
        if not line.published and dash in used:
            dash = next((d for d in FREE_DASHES if d not in used), dash)
        used.add(dash)
        simulator = simulator_of(line)
        styles[line] = LineStyle(color, dash, MARKERS[simulator], simulator, line.published)
    return styles


def legend_key(styles: Iterable[LineStyle]) -> str:
    """What the colours, line styles and markers of `styles` mean, for a legend's title."""
    styles = list(styles)
    dashes = {s.dash for s in styles}
    words = ["colour: the method"]
    if SOLID in dashes:
        words.append("solid: ours, hercs' defaults")
    if PUBLISHED in dashes and any(s.hollow for s in styles):
        words.append("dashed: the authors' published")
    if any(s.dash not in (SOLID, PUBLISHED) for s in styles):
        words.append("other lines: a changed setting")
    sims = sorted({s.simulator for s in styles}, key=list(MARKERS).index)
    marks = [f"{MARKERS[v].words}: {SIMULATOR_WORDS[v]}" for v in sims]
    return "\n".join(["; ".join(words[:2]), *(["; ".join(words[2:])] if words[2:] else []),
                      *marks])
