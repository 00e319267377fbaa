"""StackedCells, the core of a learner process serving several cells (issue 56): each cell's
loop and learner end where a lone `LearnerLoop` fed the same batches ends (weights, Adam
state, versions, epochs, the epoch's losses), when a cell waits a step, leaves to go on alone,
or diverges; and a cell unlike the others is refused by name."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.config import HercsConfig, apply_overrides
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.loop import LearnerLoop
from hercs.learner.stacked_cells import StackedCells
from hercs.rl.normalizer import Normalizer
from hercs.wire.served import ReplayCounters, ServedBatch
from tests.support import random_transition_batch
from tests.unit.learner.test_stacked import assert_same_state

B, MINIBATCHES, CYCLES = 32, 3, 2


def config(*overrides: str) -> HercsConfig:
    return apply_overrides(HercsConfig(), ["task.name=push", "ddpg.hidden_size=64",
                                           f"ddpg.batch_size={B}", "training.epochs=3",
                                           f"training.cycles_per_epoch={CYCLES}",
                                           f"training.minibatches_per_cycle={MINIBATCHES}",
                                           *overrides])


def counters(samples: int) -> ReplayCounters:
    return ReplayCounters(samples=samples, inserts=samples, env_steps=50 * samples,
                          size_transitions=50 * samples)


def loop_of(cfg: HercsConfig, seed: int) -> LearnerLoop:
    learner = DDPGLearner(spec=cfg.task.spec, config=cfg.ddpg, seed=seed,
                          precision=cfg.learner.precision)
    return LearnerLoop(learner=learner, epochs=cfg.training.epochs, cycles_per_epoch=CYCLES,
                       clusters=cfg.cluster.k, replay_status=counters)


def served(cfg: HercsConfig, cell: int, cycle: int, *, nan: bool = False) -> ServedBatch:
    """A batch as a cell's replay would serve it: its own normaliser stats, which change."""
    spec = cfg.task.spec
    rng = np.random.default_rng(100 * cell + cycle)
    o_norm, g_norm = Normalizer(spec.obs_dim), Normalizer(spec.goal_dim)
    o_norm.update(rng.normal(cell, 1.0, size=(40 + cycle, spec.obs_dim)))
    g_norm.update(rng.normal(size=(40 + cycle, spec.goal_dim)))
    minibatches = [random_transition_batch(spec, B, seed=10_000 * cell + 10 * cycle + i)
                   for i in range(MINIBATCHES)]
    if nan:
        minibatches = [m._replace(r=np.full_like(m.r, np.nan)) for m in minibatches]
    return ServedBatch(minibatches=minibatches, o_stats=o_norm.state_dict(),
                       g_stats=g_norm.state_dict(),
                       cluster_draws=np.zeros(cfg.cluster.k, np.int64),
                       samples_served=(cycle + 1) * MINIBATCHES)


def assert_same_cell(got: LearnerLoop, want: LearnerLoop) -> None:
    assert (got.version, got.cycle, got.epoch) == (want.version, want.cycle, want.epoch)
    assert got.learner.updates == want.learner.updates
    assert got.learner.target_updates == want.learner.target_updates
    assert sorted(got.pending) == sorted(want.pending)
    for epoch, snap in want.pending.items():
        for name, value in snap.losses.items():
            assert got.pending[epoch].losses[name] == pytest.approx(value, rel=1e-4,
                                                                    abs=1e-6), name
    assert_same_state(got.learner.state_dict(), want.learner.state_dict())


def test_each_cell_of_a_stack_ends_where_its_lone_loop_ends() -> None:
    cfg = config()
    seeds = (1, 2, 3)
    alone = {f"c{s}": loop_of(cfg, s) for s in seeds}
    cells = StackedCells()
    for s in seeds:
        cells.join(f"c{s}", loop_of(cfg, s))
    for cycle in range(CYCLES * 2):
        batches = {name: served(cfg, int(name[1:]), cycle) for name in alone}
        for name, loop in alone.items():
            want = loop.step(batches[name])
        outcome = cells.step(batches)
        assert not outcome.diverged
        assert outcome.results["c1"] == want  # same version; an epoch ends at the same cycle
    assert [r.epoch_ended for r in outcome.results.values()] == [2, 2, 2]
    cells.write_back()
    for name, loop in alone.items():
        assert_same_cell(cells.loops[name], loop)
    assert cells.restacks == 1


def test_a_cell_without_a_batch_waits_and_the_others_go_on() -> None:
    """Cell b's replay is down for two cycles: a and c train on, b's loop and learner do not
    change, and when its batches come back it ends where its lone twin does."""
    cfg = config()
    alone = {n: loop_of(cfg, s) for n, s in (("a", 1), ("b", 2), ("c", 3))}
    cells = StackedCells()
    for n, s in (("a", 1), ("b", 2), ("c", 3)):
        cells.join(n, loop_of(cfg, s))
    b_cycle = 0
    for cycle in range(5):
        down = cycle in (1, 2)
        batches = {n: served(cfg, i, cycle if n != "b" else b_cycle)
                   for i, n in enumerate(alone) if not (down and n == "b")}
        for n, batch in batches.items():
            alone[n].step(batch)
        if down:
            before = cells.loops["b"].version
        outcome = cells.step(batches)
        assert set(outcome.results) == set(batches)
        if down:
            assert cells.loops["b"].version == before
        else:
            b_cycle += 1
    cells.write_back()
    for n, loop in alone.items():
        assert_same_cell(cells.loops[n], loop)
    assert cells.restacks == 3  # all three, a and c, all three again


def test_a_cell_that_leaves_goes_on_alone_and_one_that_joins_late_keeps_its_age() -> None:
    cfg = config()
    twins = {n: loop_of(cfg, s) for n, s in (("a", 1), ("b", 2))}
    cells = StackedCells()
    cells.join("a", loop_of(cfg, 1))
    for cycle in range(2):  # b trains alone first, then joins with its own Adam step count
        twins["a"].step(served(cfg, 0, cycle))
        twins["b"].step(served(cfg, 1, cycle))
        cells.step({"a": served(cfg, 0, cycle)})
    late = loop_of(cfg, 2)
    for cycle in range(2):
        late.step(served(cfg, 1, cycle))
    cells.join("b", late)
    for cycle in range(2, 4):
        for n, i in (("a", 0), ("b", 1)):
            twins[n].step(served(cfg, i, cycle))
        cells.step({"a": served(cfg, 0, cycle), "b": served(cfg, 1, cycle)})
    gone = cells.leave("a")  # a's learner now holds its slot: it goes on as a lone loop
    assert cells.names == ("b",)
    gone.step(served(cfg, 0, 4))
    twins["a"].step(served(cfg, 0, 4))
    cells.step({"b": served(cfg, 1, 4)})
    twins["b"].step(served(cfg, 1, 4))
    assert_same_cell(gone, twins["a"])
    cells.write_back()
    assert_same_cell(cells.loops["b"], twins["b"])


def test_a_cell_whose_update_turns_non_finite_leaves_with_its_run_named_and_others_go_on(
) -> None:
    cfg = config()
    twin = loop_of(cfg, 1)
    cells = StackedCells()
    cells.join("good", loop_of(cfg, 1))
    cells.join("bad", loop_of(cfg, 2))
    for cycle in range(3):
        twin.step(served(cfg, 0, cycle))
        batches = {"good": served(cfg, 0, cycle), "bad": served(cfg, 1, cycle, nan=cycle == 1)}
        batches = {n: b for n, b in batches.items() if n in cells.names}
        outcome = cells.step(batches)
        if cycle == 1:
            assert set(outcome.diverged) == {"bad"}
            message = str(outcome.diverged["bad"])
            assert "training diverged in epoch 1, cycle 2 of 2" in message
            assert f"update {MINIBATCHES + 1}: critic_loss" in message
            assert cells.names == ("good",)
            with pytest.raises(KeyError, match="bad"):
                cells.step({"bad": batches["bad"]})
        else:
            assert set(outcome.results) == set(batches)
    cells.write_back()
    assert_same_cell(cells.loops["good"], twin)


def test_cells_that_cannot_share_an_update_are_refused_by_name() -> None:
    cells = StackedCells()
    cells.join("a", loop_of(config(), 1))
    with pytest.raises(ValueError, match=r"ddpg.hidden_size 32 against 64"):
        cells.join("b", loop_of(config("ddpg.hidden_size=32"), 2))
    with pytest.raises(ValueError, match=r"learner.precision 'bf16', the stack's is 'fp32'"):
        cells.join("c", loop_of(config("learner.precision=bf16"), 3))
    with pytest.raises(ValueError, match="in the stack already"):
        cells.join("a", loop_of(config(), 1))
    with pytest.raises(ValueError, match=r"learner.precision 'tf32'"):
        StackedCells(precision="tf32")
    bigger = config("training.minibatches_per_cycle=4")
    cells.join("d", loop_of(config(), 4))
    batch = served(config(), 0, 0)
    wider = served(bigger, 1, 0)
    wider = ServedBatch(minibatches=[*wider.minibatches, wider.minibatches[0]],
                        o_stats=wider.o_stats, g_stats=wider.g_stats,
                        cluster_draws=wider.cluster_draws, samples_served=4)
    with pytest.raises(ValueError, match=r"different numbers of minibatches \(\[3, 4\]\)"):
        cells.step({"a": batch, "d": wider})


def test_learner_stack_refuses_run_folders_it_cannot_serve(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """`hercs learner-stack`'s check of its run folders, before any session opens: a folder
    without a run, a run whose hercs up starts its own learner, runs that do not update
    alike; each refused with the file or the setting named."""
    from hercs.config import save_yaml
    from hercs.errors import ConfigError
    from hercs.learner.stacked_shell import load_cells

    def run_dir(name: str, *overrides: str):  # type: ignore[no-untyped-def]
        folder = tmp_path / name
        folder.mkdir()
        save_yaml(config(f"run.name={name}", *overrides), folder / "config.yaml")
        return folder

    with pytest.raises(ConfigError, match=r"no config\.yaml"):
        load_cells([tmp_path / "nothing"])
    own = run_dir("own")
    with pytest.raises(ConfigError, match=r"launch\.learner_elsewhere is false"):
        load_cells([own])
    a = run_dir("a", "launch.learner_elsewhere=true")
    b = run_dir("b", "launch.learner_elsewhere=true", "training.minibatches_per_cycle=4")
    with pytest.raises(ConfigError, match=r"'a': 3, 'b': 4"):
        load_cells([a, b])
    assert [c.run.name for c in load_cells([a])] == ["a"]
