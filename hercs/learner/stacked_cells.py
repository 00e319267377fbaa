"""Several cells' learner loops trained by one stacked update: the pure core of a learner
process that serves K cells of a grid (issue 56).

Each cell keeps what is its own: its `DDPGLearner` (normalisers, counters, the state its
checkpoint holds), its `LearnerLoop` (cycles, epochs, versions, metrics rows) and its batches.
What the cells share is the update: one `StackedDDPG` holds the weights and Adam moments of the
cells that train in a step, and is rebuilt from the cells' learners when that set changes (a
cell joins, leaves, diverges, or has no batch this step because its replay is slow or down),
so a cell that waits costs the others nothing but one restack.

A cell's learner holds its slot's state only once written back (`write_back`): before its
checkpoint, and when it leaves. `weights_of` writes back the actor alone, for the broadcast.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import torch

from hercs.errors import Diverged
from hercs.learner.ddpg import LOSS_NAMES, DDPGLearner
from hercs.learner.divergence import nonfinite_losses
from hercs.learner.loop import CycleResult, LearnerLoop
from hercs.learner.stacked import StackedDDPG, stacked_inputs
from hercs.wire.served import ServedBatch

STACKED_PRECISIONS = ("fp32", "bf16")


@dataclass
class StepOutcome:
    """What one stacked step did to each cell that had a batch."""

    results: dict[str, CycleResult] = field(default_factory=dict)
    """The cells whose cycle completed, with its result (broadcast, maybe an epoch's end)."""
    diverged: dict[str, Diverged] = field(default_factory=dict)
    """The cells whose update turned non-finite: out of the stack, their learners as last
    written back (nothing of this cycle), the error placed in their run as a lone learner's."""


class StackedCells:
    """The cells of one learner process, by name, in the order they joined."""

    def __init__(self, *, precision: str = "fp32") -> None:
        if precision not in STACKED_PRECISIONS:
            raise ValueError(f"learner.precision {precision!r}: a stack of cells runs "
                             f"{' or '.join(STACKED_PRECISIONS)}")
        self.precision = precision
        self.loops: dict[str, LearnerLoop] = {}
        self._stack: StackedDDPG | None = None
        self._members: tuple[str, ...] = ()
        self.restacks = 0
        """How often the stack was rebuilt (a changed set of cells training together)."""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.loops)

    def join(self, name: str, loop: LearnerLoop) -> None:
        """Add a cell: `loop` and its learner, of any age (a resumed one keeps its Adam step
        count). Its networks and DDPG settings must be the stack's."""
        if name in self.loops:
            raise ValueError(f"cell {name!r} is in the stack already")
        learner = loop.learner
        if learner.device.type != "cpu":
            raise ValueError(f"cell {name!r}: its learner is on {learner.device}; a stack of "
                             "cells runs on the CPU")
        if learner.precision != self.precision:
            raise ValueError(f"cell {name!r}: learner.precision {learner.precision!r}, the "
                             f"stack's is {self.precision!r} (one comparison, one precision)")
        if self.loops:
            first_name, first = next(iter(self.loops.items()))
            mismatch = _mismatch(first.learner, learner)
            if mismatch:
                raise ValueError(f"cell {name!r} cannot share an update with {first_name!r}: "
                                 f"{mismatch}")
        self.loops[name] = loop

    def leave(self, name: str) -> LearnerLoop:
        """The cell out of the stack, its learner holding its slot's state (a lone learner
        can go on from it, or checkpoint it)."""
        if name not in self.loops:
            raise KeyError(f"no cell {name!r} in the stack")
        if name in self._members:
            self._unstack(keep=self.names)
        return self.loops.pop(name)

    def write_back(self, names: Iterable[str] | None = None) -> None:
        """Write these cells' slots (default: all) into their learners, so that each
        learner's `state_dict()` is its cell's checkpoint."""
        if self._stack is None:
            return
        for name in self.names if names is None else names:
            if name in self._members:
                self._stack.store_learner(self._members.index(name), self.loops[name].learner)

    def weights_of(self, name: str) -> DDPGLearner:
        """The cell's learner with its actor μ current: what its weights broadcast reads."""
        learner = self.loops[name].learner
        if self._stack is not None and name in self._members:
            self._stack.store_actor(self._members.index(name), learner)
        return learner

    def step(self, batches: Mapping[str, ServedBatch]) -> StepOutcome:
        """One cycle of every cell in `batches` (each its own `ServedBatch`): its normaliser
        stats adopted, one stacked update per minibatch, the targets' update, and its loop's
        bookkeeping. Cells without a batch this step wait; nothing of theirs changes."""
        unknown = sorted(set(batches) - set(self.loops))
        if unknown:
            raise KeyError(f"batches for cells not in the stack: {unknown}")
        names = tuple(n for n in self.loops if n in batches)
        outcome = StepOutcome()
        if not names:
            return outcome
        sizes = {len(batches[n].minibatches) for n in names}
        if len(sizes) != 1:
            raise ValueError("the cells' batches hold different numbers of minibatches "
                             f"({sorted(sizes)}); cells that share an update share "
                             "training.minibatches_per_cycle")
        stack = self._stack_for(names)
        learners = [self.loops[n].learner for n in names]
        for name, learner in zip(names, learners, strict=True):
            learner.set_normalizer_state(batches[name].o_stats, batches[name].g_stats)
        bad: dict[int, str] = {}
        for i in range(sizes.pop()):
            inputs = stacked_inputs(learners, [batches[n].minibatches[i] for n in names])
            losses = stack.train(*inputs).double()
            finite = torch.isfinite(losses).all(dim=1).tolist()
            for k, learner in enumerate(learners):
                if k in bad:
                    continue  # its later updates are not its run's: it stops at the first
                if not finite[k]:
                    bad[k] = (f"update {learner.updates + 1}: "
                              f"{nonfinite_losses(LOSS_NAMES, losses[k].tolist())}")
                    continue
                learner.count_update(losses[k])
        for k in stack.nonfinite_slots():
            bad.setdefault(k, f"after update {learners[k].updates}: a parameter of the actor "
                              "or the critic is not finite")
        stack.update_targets()
        for k, name in enumerate(names):
            loop = self.loops[name]
            if k in bad:
                outcome.diverged[name] = loop.diverged(Diverged(bad[k]))
                continue
            learners[k].target_updates += 1
            outcome.results[name] = loop.account(batches[name])
        if outcome.diverged:  # out without writing back what turned non-finite
            self._unstack(keep=[n for n in self.names if n not in outcome.diverged])
            for name in outcome.diverged:
                del self.loops[name]
        return outcome

    def _unstack(self, *, keep: Iterable[str]) -> None:
        """Write the `keep` cells' slots back and drop the stack (the next step builds one
        of the cells it trains)."""
        self.write_back(keep)
        self._stack, self._members = None, ()

    def _stack_for(self, names: tuple[str, ...]) -> StackedDDPG:
        """The stack of exactly these cells: the current one, or a new one built from their
        learners once the current one's slots are written back."""
        if self._stack is None or self._members != names:
            self._unstack(keep=self.names)
            first = self.loops[names[0]].learner
            self._stack = StackedDDPG(spec=first.spec, config=first.config,
                                      learners=[self.loops[n].learner for n in names],
                                      precision=self.precision)
            self._members = names
            self.restacks += 1
        return self._stack


def _mismatch(a: DDPGLearner, b: DDPGLearner) -> str:
    """What keeps two learners out of one stack ('' if nothing)."""
    dims = [(f"{what}_dim", getattr(a.spec, f"{what}_dim"), getattr(b.spec, f"{what}_dim"))
            for what in ("obs", "goal", "action")]
    for field_name, mine, theirs in dims:
        if mine != theirs:
            return f"task {field_name} {theirs} against {mine}"
    if a.spec.max_action != b.spec.max_action:
        return f"max_action {b.spec.max_action} against {a.spec.max_action}"
    if a.config != b.config:
        differs = [f for f in vars(a.config) if getattr(a.config, f) != getattr(b.config, f)]
        return "ddpg settings differ: " + ", ".join(
            f"ddpg.{f} {getattr(b.config, f)!r} against {getattr(a.config, f)!r}"
            for f in differs)
    return ""
