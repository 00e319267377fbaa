"""The chaos soak's schedule (bench.faults.chaos): what is injected when, drawn up front from one
seed so that a soak can be repeated, recorded and resumed.

Two independent streams on one clock (seconds since the launch), kills and cuts, which may
overlap; a schedule runs past any plausible run (`horizon_s`). The rules: docs/FAULTS.md,
"The chaos soak"."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SERVICES = ("replay", "learner", "clusterer", "evaluator")
"""Children of `hercs up` that the launcher restarts (their ids are `<role>-0`)."""
TARGETS = (*SERVICES, "actor", "launcher")
"""Every target a kill may have: `actor` is a remote actor (the bench restarts it, as a
supervisor on its host would); `launcher` is `hercs up` itself, with the router and every
child (the bench continues the run with `hercs up --resume`)."""
DEFAULT_TARGETS = (*SERVICES, "actor")
"""The soak's targets: each service and the actors (the issue's list); `launcher` on request."""
KINDS = ("kill", "cut")


def _span(name: str, span: tuple[float, float], *, low: float = 0.0) -> None:
    if not low <= span[0] <= span[1]:
        raise ValueError(f"{name}: got {span}, expected (low, high) with {low:g} <= low <= high")


@dataclass(frozen=True)
class ChaosPlan:
    """How often and how hard; every span is (low, high) seconds, drawn uniformly."""

    kill_gap_s: tuple[float, float] = (60.0, 120.0)
    """Between two kills (and from the launch to the first), the issue's 60–120 s."""
    cut_gap_s: tuple[float, float] = (120.0, 240.0)
    """From the launch, or the end of a cut, to the next cut: a cut every 2.5–5.5 min."""
    cut_s: tuple[float, float] = (30.0, 90.0)
    """How long a cut lasts: from below Zenoh's 10 s lease ×3 to well beyond it."""
    targets: tuple[str, ...] = DEFAULT_TARGETS
    max_kills: int | None = None
    """Stop drawing kills after this many (None: until the horizon)."""
    max_cuts: int | None = None
    horizon_s: float = 6 * 3600.0
    epoch_gated: bool = False
    """Inject the i-th event (in drawn time order, from 1) as soon as the run has recorded
    epoch i, instead of at its drawn time: the schedule follows the run's progress, so a run
    on a fast machine cannot end before it (the quick soak)."""

    def __post_init__(self) -> None:
        _span("kill_gap_s", self.kill_gap_s, low=1.0)
        _span("cut_gap_s", self.cut_gap_s, low=1.0)
        _span("cut_s", self.cut_s, low=1.0)
        unknown = sorted(set(self.targets) - set(TARGETS))
        if unknown or not self.targets:
            raise ValueError(f"targets: got {list(self.targets)}, expected a non-empty subset "
                             f"of {list(TARGETS)}")
        for name in ("max_kills", "max_cuts"):
            value = getattr(self, name)
            if value is not None and value < 0:
                raise ValueError(f"{name}: got {value}, expected >= 0 or None")


QUICK_PLAN = ChaosPlan(kill_gap_s=(12.0, 15.0), cut_gap_s=(20.0, 24.0), cut_s=(12.0, 12.0),
                       targets=("actor",), max_kills=1, max_cuts=1, epoch_gated=True)
"""CI: one remote actor killed (the bench's own supervisor path) once epoch 1 is recorded, its
host cut for 12 s (beyond Zenoh's 10 s lease) once epoch 2 is. With one actor (QUICK_SHAPE)
the run cannot go on while it is dead or cut off (the replay's rate limiter holds the
learner), so on a machine of any speed both faults fall inside the run and epochs follow
the recovery from each."""


@dataclass(frozen=True)
class Event:
    """One injection due at `at_s` on the run's clock."""

    at_s: float
    kind: str
    """"kill" or "cut"."""
    target: str
    """A kill: a service's child id (`replay-0`, …), an actor's id (`net-2`) or `launcher`;
    a cut: the id of the actor whose host's link is cut."""
    duration_s: float = 0.0
    """A cut's length (0 for a kill)."""
    after_epoch: int = 0
    """Injected once the run has recorded this epoch, whatever the clock says (0: at
    `at_s`)."""

    def __post_init__(self) -> None:
        if self.kind not in KINDS or self.at_s < 0 or self.duration_s < 0:
            raise ValueError(f"event: got kind {self.kind!r} (one of {KINDS}), at {self.at_s} "
                             f"and duration {self.duration_s} (>= 0)")

    def describe(self) -> str:
        if self.kind == "cut":
            return f"cut {self.target}'s link both ways for {self.duration_s:.0f} s"
        return f"SIGKILL {self.target}"


def draw_events(plan: ChaosPlan, *, actors: list[str], rng: np.random.Generator) -> list[Event]:
    """Every injection of `plan` up to its horizon, in time order, from one generator (the
    kill stream draws first, then the cuts; the soak records the drawn events, not only the
    seed)."""
    if not actors:
        raise ValueError("actors: got none; a chaos soak needs at least one remote actor")
    events: list[Event] = []
    at = 0.0
    while plan.max_kills is None or sum(e.kind == "kill" for e in events) < plan.max_kills:
        at += float(rng.uniform(*plan.kill_gap_s))
        if at > plan.horizon_s:
            break
        target = str(plan.targets[int(rng.integers(len(plan.targets)))])
        if target == "actor":
            target = actors[int(rng.integers(len(actors)))]
        elif target in SERVICES:
            target = f"{target}-0"
        events.append(Event(round(at, 1), "kill", target))
    at, cuts = 0.0, 0
    while plan.max_cuts is None or cuts < plan.max_cuts:
        at += float(rng.uniform(*plan.cut_gap_s))
        if at > plan.horizon_s:
            break
        length = round(float(rng.uniform(*plan.cut_s)), 1)
        events.append(Event(round(at, 1), "cut", actors[int(rng.integers(len(actors)))],
                            length))
        at += length
        cuts += 1
    events.sort(key=lambda e: (e.at_s, e.kind))
    if plan.epoch_gated:
        events = [Event(e.at_s, e.kind, e.target, e.duration_s, after_epoch=i + 1)
                  for i, e in enumerate(events)]
    return events
