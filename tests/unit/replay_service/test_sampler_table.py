"""The extension points of the replay's draw: a method's row names its sampler class, which
says what it needs and how it is built, and `cluster.share_rule` names a row of
`SHARE_RULES`; a new strategy is its module plus one row, found by the config check, the
replay's `make_sampler` and the samplers."""

from __future__ import annotations

from typing import Self

import pytest

from hercs.config import HercsConfig, apply_overrides
from hercs.errors import ConfigError, SamplingError
from hercs.rl.methods import METHODS, Method, make_sampler
from hercs.rl.samplers import (
    ClusterBalancedSampler,
    EnergyClusterSampler,
    EnergyPrioritisedSampler,
    Needs,
    SamplerSettings,
    UniformSampler,
    share_rules,
)
from hercs.rl.samplers.cluster_balanced import plan_shares
from tests.unit.replay_service.test_replay_samplers import PAPER_LIKE, _labels, _store


def test_each_method_is_its_sampler_and_needs_what_the_sampler_reads() -> None:
    assert {name: (m.sampler, m.needs) for name, m in METHODS.items()} == {
        "her": (UniformSampler, Needs()),
        "her-cs": (ClusterBalancedSampler, Needs(clusters=True)),
        "her-ebp": (EnergyPrioritisedSampler, Needs(energy=True)),
        "her-ebp-cs": (EnergyClusterSampler, Needs(clusters=True, energy=True)),
    }


def test_a_new_sampler_is_one_class_and_its_methods_row(monkeypatch: pytest.MonkeyPatch) -> None:
    class EveryOtherSampler(UniformSampler):
        """A made-up strategy: HER's draw, built from its own reading of the settings."""

        @classmethod
        def from_settings(cls, settings: SamplerSettings) -> Self:
            return cls(num_clusters=settings.k + 1)

    monkeypatch.setitem(METHODS, "her-eo", Method("her-eo", "HER-EO", EveryOtherSampler))
    config = apply_overrides(HercsConfig(), ["run.method=her-eo"])
    sampler = make_sampler(config.run.method, config.sampler_settings)
    assert type(sampler) is EveryOtherSampler and sampler.num_clusters == config.cluster.k + 1


def test_the_reference_share_rule_is_a_row(monkeypatch: pytest.MonkeyPatch) -> None:
    """The two rules the config accepts are the table's; with cluster 7 empty the reference
    splits the batch 7 ways (36 each) where every-cluster splits it 8 ways (32)."""
    assert list(share_rules.SHARE_RULES) == ["every-cluster", "reference"]
    index = _store(_labels(PAPER_LIKE)).sampling_index
    shares = {rule: plan_shares(index, k=8, repeat=4, batch_size=256, share_rule=rule)
              for rule in share_rules.SHARE_RULES}
    assert shares["every-cluster"].member_draws[0] == 32  # type: ignore[union-attr]
    assert shares["reference"].member_draws[0] == 36  # type: ignore[union-attr]
    with pytest.raises(ConfigError, match=r"cluster.share_rule.*'half-shares'"):
        apply_overrides(HercsConfig(), ["cluster.share_rule=half-shares"])
    monkeypatch.setitem(share_rules.SHARE_RULES, "half-shares", lambda max_label, k: 2 * k)
    config = apply_overrides(HercsConfig(),
                             ["run.method=her-cs", "cluster.share_rule=half-shares"])
    assert make_sampler("her-cs", config.sampler_settings).share_rule == "half-shares"
    plan = plan_shares(index, k=8, repeat=4, batch_size=256, share_rule="half-shares")
    assert plan is not None and plan.member_draws[0] == 16 and plan.fill >= 128


def test_a_rule_that_shares_among_fewer_than_the_labelled_clusters_is_refused(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Its shares would not fit the batch."""
    monkeypatch.setitem(share_rules.SHARE_RULES, "two", lambda max_label, k: 2)
    index = _store(_labels(PAPER_LIKE)).sampling_index
    with pytest.raises(SamplingError, match=r"share rule 'two'.*2 clusters.*label 6"):
        plan_shares(index, k=8, repeat=4, batch_size=256, share_rule="two")
