"""What a chaos soak is (`Shape`) and where it stands (`SoakState`, saved as
`<work>/<run>.state.json` after every injection, so that a stopped soak continues where its
clock stopped and a finished one can be measured again): bench.faults.chaos runs it,
bench.faults.chaos_report reads it back."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from bench.faults.chaos_plan import ChaosPlan, draw_events
from bench.faults.remote_actor import actor_ident


@dataclass(frozen=True)
class Shape:
    """What the soak's run is."""

    task: str = "push"
    method: str = "her-ebp-cs"
    epochs: int = 20
    actors: int = 2
    seed: int = 1
    sets: tuple[str, ...] = ()
    """Extra `--set section.field=value` of the run (the fault-free seeds get the same)."""
    stall_s: float = 1800.0
    """No line from `hercs up` for this long (it prints one a minute while it runs): the run
    is given up and the soak fails."""

    def run_name(self, chaos_seed: int | None) -> str:
        kind = "nofault" if chaos_seed is None else f"chaos{chaos_seed}"
        return f"{kind}-{self.task}-{self.method}-s{self.seed}"


QUICK_SHAPE = Shape(task="reach", method="her-cs", epochs=5, actors=1, stall_s=240.0,
                    sets=("training.cycles_per_epoch=8", "training.eval_episodes=5",
                          "cluster.fgb_size=40"))
"""CI: FetchReach, 5 epochs of 8 cycles, one remote actor: the only source of episodes, so
the run waits out QUICK_PLAN's kill and cut (epoch-gated) whatever the machine's speed, and
records epochs after the recovery from each (~1 min on 2 cores)."""


@dataclass
class SoakState:
    """Everything a stopped soak needs to go on, and a finished one to be reported."""

    name: str
    chaos_seed: int | None
    quick: bool
    shape: dict[str, Any]
    plan: dict[str, Any] | None
    events: list[dict[str, Any]]
    next_event: int = 0
    elapsed_s: float = 0.0
    """The run's clock when the state was saved (time the bench was stopped is not on it)."""
    injections: list[dict[str, Any]] = field(default_factory=list)
    progress: list[tuple[float, str]] = field(default_factory=list)
    """`hercs up`'s stdout lines, each at its time on the run's clock."""
    actors: list[dict[str, Any]] = field(default_factory=list)
    up_exits: list[int] = field(default_factory=list)
    """The exit status of each `hercs up` (one per launch; a killed launcher's -9)."""
    launches: list[str] = field(default_factory=list)
    """When `hercs up` was started, and its command line."""
    notes: list[str] = field(default_factory=list)
    """What went wrong (a stall, an actor that died unasked); empty in a clean soak."""
    loads: list[float] = field(default_factory=list)
    finished: bool = False

    def save(self, path: Path) -> None:
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(self), indent=1) + "\n")
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> SoakState:
        data = json.loads(path.read_text())
        data["progress"] = [(float(t), str(line)) for t, line in data["progress"]]
        return cls(**{f.name: data[f.name] for f in fields(cls) if f.name in data})


def _plain(value: Any) -> Any:
    """`value` as it reads back from JSON (tuples as lists), so that a saved state and a new
    one of the same options compare equal."""
    return json.loads(json.dumps(value))


def new_state(shape: Shape, *, chaos_seed: int | None, plan: ChaosPlan | None,
              quick: bool) -> SoakState:
    """A soak not yet started: its whole schedule drawn from `chaos_seed` (none for a
    fault-free seed, `chaos_seed` None)."""
    actors = [actor_ident(i + 1) for i in range(shape.actors)]
    events = ([] if plan is None or chaos_seed is None else
              draw_events(plan, actors=actors, rng=np.random.default_rng(chaos_seed)))
    return SoakState(name=shape.run_name(chaos_seed), chaos_seed=chaos_seed, quick=quick,
                     shape=_plain(asdict(shape)),
                     plan=None if plan is None else _plain(asdict(plan)),
                     events=[asdict(e) for e in events])
