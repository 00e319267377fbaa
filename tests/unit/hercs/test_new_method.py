"""A new sampling method is one sampler module (cluster_uniform_sampler.py) plus one row of
hercs.rl.methods.METHODS: with the row registered and nothing else edited, the replay's
sampler factory builds it, the clusterer's and the lockstep gate's need check, the config's
energy check, the CLI's and the sweep's choices and the plots' labels, order and colours all
take it from the row."""

from __future__ import annotations

from collections.abc import Iterator
from typing import ClassVar

import numpy as np
import pytest

from hercs.apps.plots.series import method_label, method_rank
from hercs.apps.plots.style import METHOD_COLORS, Line, assign_styles
from hercs.apps.sweep.cells import reserved_variant
from hercs.apps.sweep.grid import build_parser
from hercs.config import HercsConfig, apply_overrides
from hercs.errors import ConfigError
from hercs.rl.methods import METHODS, Method, make_sampler
from hercs.rl.samplers import Needs
from tests.unit.hercs.cluster_uniform_sampler import ClusterUniformSampler
from tests.unit.replay_service.test_replay_samplers import PAPER_LIKE, _labels, _store

ROW = Method("her-cu", "HER-CU", ClusterUniformSampler)
"""The one row a new method adds."""


@pytest.fixture
def registered(monkeypatch: pytest.MonkeyPatch) -> Iterator[Method]:
    monkeypatch.setitem(METHODS, ROW.name, ROW)
    yield ROW


def test_the_replays_factory_builds_the_new_sampler_and_it_draws_by_its_rule(
        registered: Method) -> None:
    """Seven labelled clusters of 2,000 down to 3 episodes: each gets 1/7 of the draws."""
    config = apply_overrides(HercsConfig(), [f"run.method={registered.name}"])
    sampler = make_sampler(config.run.method, config.sampler_settings)
    assert type(sampler) is ClusterUniformSampler and sampler.k == config.cluster.k
    store = _store(_labels(PAPER_LIKE))
    rng = np.random.default_rng(0)
    per_cluster = np.zeros(len(PAPER_LIKE), np.int64)
    for _ in range(200):
        _, info = sampler.sample(store, 256, rng)
        per_cluster += info.cluster_counts
    share = per_cluster / per_cluster.sum()
    # 51,200 draws: a share of 1/7 has a standard deviation of 0.0015; 0.01 is 6.5 of them
    assert np.abs(share[:7] - 1 / 7).max() < 0.01 and per_cluster[7] == 0


def test_the_clusterer_the_lockstep_gate_and_the_config_read_its_needs(
        registered: Method, monkeypatch: pytest.MonkeyPatch) -> None:
    """`RunConfig.uses_clusters` is what the clusterer (whether it fits) and the lockstep gate
    (whether it waits for a model) read; the EBP check reads `needs.energy`."""
    assert registered.needs == Needs(clusters=True)
    config = apply_overrides(HercsConfig(), [f"run.method={registered.name}"])
    assert config.run.uses_clusters
    maze = apply_overrides(HercsConfig(), ["task.name=PointMaze_UMaze-v3",
                                           f"run.method={registered.name}"])
    assert maze.run.method == registered.name, "it needs no energy: any task"

    class EnergyHungry(ClusterUniformSampler):
        needs: ClassVar[Needs] = Needs(clusters=True, energy=True)

    monkeypatch.setitem(METHODS, "her-hungry", Method("her-hungry", "HER-H", EnergyHungry))
    with pytest.raises(ConfigError, match=r"run\.method: got 'her-hungry'.*'her-cu'.*no "
                                          r"trajectory energy"):
        apply_overrides(HercsConfig(), ["task.name=PointMaze_UMaze-v3", "run.method=her-hungry"])


def test_the_cli_the_sweep_and_the_plots_take_it_from_the_row(registered: Method) -> None:
    assert build_parser().parse_args(["--methods", "her", registered.name]).methods == [
        "her", registered.name]
    assert reserved_variant(registered.name) and reserved_variant("cu")
    assert method_label(f"{registered.name}/lockstep").startswith("HER-CU, lockstep")
    assert method_rank(registered.name) == (4, registered.name), "after the paper's four"
    styles = assign_styles([Line(m) for m in (*METHOD_COLORS, registered.name)])
    assert styles[Line(registered.name)].color not in METHOD_COLORS.values()
