"""`hercs learner-stack RUN_DIR...`: one learner process for several runs (issue 56), a thin
shell around `StackedCells`.

Each run (a cell) keeps all that is its own: a Zenoh session to its own router, its
`LearnerService` (resume from its checkpoint, weights broadcast, evaluations, metrics.csv,
checkpoints and policy files), its prefetcher, and its run's `hercs up`, started with
`launch.learner_elsewhere` so that it starts no learner of its own. What the cells share is the
update: each step trains the cells that have a batch (one waits `GATHER_GRACE_S` for the others
once the first is in), so a cell whose replay is down or slow sits steps out while the rest
train on.

A cell that finished its epochs leaves the stack and waits for its last evaluations as a lone
learner would (`training.eval_wait_s`), then says `RunProgress.finished`, which ends its run. A
cell whose update turns non-finite leaves at once without a checkpoint of that cycle and says
`RunProgress.diverged` (its `hercs up` exits 4); the others go on. Killed, the process leaves
each cell's newest checkpoint, from which each resumes (here or as a lone learner). Exit
status, once every cell ended (each cell's own run says how it ended): 0 all finished, 1 a
cell's evaluations did not come, else 4 a cell diverged.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from hercs.config import HercsConfig, load_yaml
from hercs.errors import ConfigError, Diverged
from hercs.learner.builder import LearnerBuilder
from hercs.learner.learner_shell import LearnerService
from hercs.learner.prefetch import Prefetcher
from hercs.learner.stacked_cells import StackedCells
from hercs.net.service_shell import ServiceRuntime, service_main
from hercs.run.rundir import RunDir, run_dir_of
from hercs.wire.served import ServedBatch

log = logging.getLogger("hercs.learner")

GATHER_GRACE_S = 0.5
"""Once one cell's batch is in, how long a step waits for the others' before it trains
without them. Cells' replays serve at their actors' pace, a cycle apart by seconds; waiting
this long keeps them in one stack most steps, and a cell that misses it trains the next."""

POLL_S = 0.05
"""How often a step looks at each cell's prefetcher while it waits."""


@dataclass
class Cell:
    name: str
    service: LearnerService
    runtime: ServiceRuntime
    prefetcher: Prefetcher | None = None
    waited_before: float = 0.0
    finishing_until: float | None = None
    """Set once its epochs are done: when its wait for the last evaluations ends."""
    status: int | None = None
    """Once the cell ended: 0 finished, 1 its evaluations did not come, 4 diverged."""
    closed: bool = False


def load_cells(run_dirs: list[Path]) -> list[HercsConfig]:
    """Each run directory's config.yaml (written by its `hercs up`: its router's concrete
    endpoints), checked to be a run whose learner is elsewhere."""
    configs = []
    for run_dir in run_dirs:
        path = RunDir(run_dir).config
        if not path.is_file():
            raise ConfigError(f"{run_dir}: no config.yaml (start the run first: hercs up ... "
                              "--set launch.learner_elsewhere=true)")
        config = load_yaml(path)
        if not config.launch.learner_elsewhere:
            raise ConfigError(f"{path}: launch.learner_elsewhere is false, so its hercs up "
                              "starts a learner of its own; a run served by a stack is started "
                              "with --set launch.learner_elsewhere=true")
        configs.append(config)
    names = [c.run.name for c in configs]
    if len(set(names)) != len(names):
        raise ConfigError(f"a run is named twice: {names}")
    per_cycle = {c.run.name: c.training.minibatches_per_cycle for c in configs}
    if len(set(per_cycle.values())) > 1:
        raise ConfigError("the runs of one stack update together, so they share "
                          f"training.minibatches_per_cycle; these have {per_cycle}")
    return configs


def run(run_dirs: list[Path], *, ident: str | None = None) -> int:
    """`hercs learner-stack`: train every run of `run_dirs` to its end in this process."""
    configs = load_cells(run_dirs)
    return service_main(role="learner", config=configs[0], ident=ident or "learner-stack",
                        body=lambda runtime: StackedLearner(runtime, configs).run())


class StackedLearner:
    """The process's cells. Each cell has a runtime (Zenoh session, stop event) of its own, so
    that a cell that ended closes its session and its prefetcher while the others go on; the
    process's runtime (`process`, of the first run, from `service_main`) carries the stop
    signal, which stops every cell."""

    def __init__(self, process: ServiceRuntime, configs: list[HercsConfig]) -> None:
        self.stop = process.stop
        precision = configs[0].learner.precision
        try:
            self.stack = StackedCells(precision=precision)
        except ValueError as exc:
            raise ConfigError(f"{configs[0].run.name}: {exc}") from None
        self.cells: dict[str, Cell] = {}
        self._cell_stops = [threading.Event() for _ in configs]
        process.start_thread(self._pass_stop_on, name="stop-cells")
        try:
            self._open(process, configs)
        except BaseException:
            self._close_all()
            raise
        log.info("learner stack of %d runs (%s), %s", len(self.cells),
                 ", ".join(self.cells), precision)

    def _pass_stop_on(self) -> None:
        """The stop signal stops every cell (a wait for its router included)."""
        self.stop.wait()
        for stop in self._cell_stops:
            stop.set()

    def _open(self, process: ServiceRuntime, configs: list[HercsConfig]) -> None:
        for config, stop in zip(configs, self._cell_stops, strict=True):
            runtime = ServiceRuntime(config=config, role="learner", ident=process.ident,
                                     stop=stop)
            run_dir = run_dir_of(config.run)
            service = LearnerService(parts=LearnerBuilder(config), runtime=runtime,
                                     run_dir=run_dir)
            cell = Cell(config.run.name, service, runtime)
            self.cells[cell.name] = cell
            try:
                self.stack.join(cell.name, service.loop)
            except ValueError as exc:
                raise ConfigError(f"{run_dir}: {exc}") from None

    def run(self) -> int:
        """Train until every cell ended (or the stop signal): 0 all finished, 1 a cell's
        evaluations did not come, else 4 a cell diverged."""
        try:
            for cell in self.cells.values():
                self._start(cell)
            while not self.stop.is_set() and any(c.status is None for c in self.cells.values()):
                batches = self._gather()
                if batches:
                    self._step(batches)
                self._finish_waiting()
            if self.stop.is_set():
                return 0
            statuses = {c.status for c in self.cells.values()}
            return 1 if 1 in statuses else 4 if 4 in statuses else 0
        finally:
            self._close_all()

    def _close_all(self) -> None:
        for cell in self.cells.values():
            self._close(cell)

    def _close(self, cell: Cell) -> None:
        if cell.closed:
            return
        cell.closed = True
        cell.runtime.stop.set()
        cell.service.close()
        cell.runtime.close()

    def _start(self, cell: Cell) -> None:
        service = cell.service
        if service.loop.done and not service.loop.pending:
            log.info("%s: its %d epochs are already done", cell.name, service.settings.epochs)
            service.publish_progress(finished=True)
            self._end(cell, 0)
            return
        service.publish_weights(evaluate=False, epoch=service.loop.epoch)
        service.publish_progress()
        loop = service.loop
        cell.prefetcher = service.parts.prefetcher(
            service.runtime, version=lambda: loop.version, samples_kept=service.learner.updates)
        service.prefetcher_bad = cell.prefetcher.bad_batches
        if service.loop.done:  # resumed with only its last evaluations to wait for
            self._leave(cell)

    def _training(self) -> list[Cell]:
        return [c for c in self.cells.values()
                if c.status is None and c.finishing_until is None and c.prefetcher is not None]

    def _gather(self) -> dict[str, ServedBatch]:
        """The batches of the cells that have one: wait for a first, then `GATHER_GRACE_S`
        for the rest."""
        training = self._training()
        got: dict[str, ServedBatch] = {}
        grace_ends: float | None = None
        if not training:  # only runs waiting for their last evaluations
            self.stop.wait(POLL_S)
        while training and not self.stop.is_set():
            for cell in training:
                if cell.name not in got:
                    assert cell.prefetcher is not None
                    batch = cell.prefetcher.take(0)
                    if batch is not None:
                        got[cell.name] = batch
            if len(got) == len(training):
                break
            now = time.monotonic()
            if got and grace_ends is None:
                grace_ends = now + GATHER_GRACE_S
            if grace_ends is not None and now >= grace_ends:
                break
            self.stop.wait(POLL_S)
            if not got and any(c.finishing_until is not None and c.status is None
                               for c in self.cells.values()):
                break  # a finishing cell's evaluations are looked at between waits
        return got

    def _step(self, batches: dict[str, ServedBatch]) -> None:
        outcome = self.stack.step(batches)
        for name, exc in outcome.diverged.items():
            self._diverged(self.cells[name], exc)
        for name, result in outcome.results.items():
            cell = self.cells[name]
            service, prefetcher = cell.service, cell.prefetcher
            assert prefetcher is not None
            self.stack.weights_of(name)  # the actor its broadcast reads
            service.publish_weights(evaluate=result.epoch_ended is not None,
                                    epoch=result.epoch_ended or service.loop.epoch)
            prefetcher.cycle_done()
            if result.epoch_ended is not None:
                service.batch_wait_s[result.epoch_ended] = (prefetcher.waiting_s
                                                            - cell.waited_before)
                cell.waited_before = prefetcher.waiting_s
                self.stack.write_back([name])
                try:
                    service.checkpoint()
                except Diverged as exc:
                    self.stack.leave(name)
                    self._diverged(cell, exc)
                    continue
            service.publish_progress()
            service.record_evals(block=False)
            if service.loop.done:
                self._leave(cell)

    def _leave(self, cell: Cell) -> None:
        """Its epochs are done: out of the stack, to wait for its last evaluations."""
        if cell.name in self.stack.loops:
            self.stack.leave(cell.name)
        cell.finishing_until = time.monotonic() + cell.service.settings.eval_wait_s
        log.info("%s: its %d epochs are done; waiting for its last evaluations", cell.name,
                 cell.service.settings.epochs)

    def _finish_waiting(self) -> None:
        for cell in self.cells.values():
            if cell.status is not None or cell.finishing_until is None:
                continue
            service = cell.service
            service.record_evals(block=False)
            if not service.loop.pending:
                service.publish_progress(finished=True)
                self._end(cell, 0)
            elif time.monotonic() >= cell.finishing_until:
                log.error("%s: no evaluation arrived for epoch(s) %s within %.0f s", cell.name,
                          sorted(service.loop.pending), service.settings.eval_wait_s)
                self._end(cell, 1)

    def _diverged(self, cell: Cell, exc: Diverged) -> None:
        service = cell.service
        log.error("%s: %s; %s; the other runs go on", cell.name, exc,
                  service.kept_checkpoint())
        service.publish_progress(diverged=True)
        self._end(cell, 4)

    def _end(self, cell: Cell, status: int) -> None:
        cell.status = status
        self._close(cell)
        log.info("%s: ended (%d); %d run(s) go on", cell.name, status,
                 sum(1 for c in self.cells.values() if c.status is None))
