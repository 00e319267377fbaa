"""hercs.config.unsaved: the fields added after runs had saved configs without them say what
those runs ran with, in their metadata and their docstring, and `hercs plot` keys such a run
by it."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import itertools

import pytest

from hercs.apps.plots.series import DEFAULT_LAG, PolicyLag, energy_epsilon, policy_lag
from hercs.config import HercsConfig, TrainingConfig
from hercs.config.algorithm import EnergyConfig
from hercs.config.deploy import ActorConfig, LearnerConfig
from hercs.config.unsaved import UNSAVED, unsaved_default

UNSAVED_FIELDS = {(LearnerConfig, "prefetch_depth"): 3, (ActorConfig, "insert_queue"): 2,
                  (TrainingConfig, "max_policy_lag"): -1, (EnergyConfig, "epsilon"): 1e-6}


def _docstring(section: type, name: str) -> str:
    """The string right after the field's annotated assignment in its class body."""
    body = ast.parse(inspect.getsource(section)).body[0].body  # type: ignore[attr-defined]
    for node, after in itertools.pairwise(body):
        if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", "") == name:
            return str(after.value.value)  # type: ignore[attr-defined]
    raise AssertionError(f"{section.__name__}.{name}: no docstring")


@pytest.mark.parametrize(("section", "name"), list(UNSAVED_FIELDS),
                         ids=[f"{s.__name__}.{n}" for s, n in UNSAVED_FIELDS])
def test_each_such_field_says_what_a_config_without_it_ran_with(section: type, name: str) -> None:
    assert unsaved_default(section, name) == UNSAVED_FIELDS[(section, name)]
    assert "saved config has no such field" in " ".join(_docstring(section, name).split())


def test_no_other_field_carries_an_unsaved_value_and_the_rest_read_as_their_default() -> None:
    marked = {(type(s), f.name) for s in vars(HercsConfig()).values()
              for f in dataclasses.fields(s) if UNSAVED in f.metadata}
    assert marked == set(UNSAVED_FIELDS)
    assert unsaved_default(ActorConfig, "num_actors") == ActorConfig().num_actors


def test_a_saved_config_without_the_fields_is_keyed_by_what_it_ran_with() -> None:
    saved = {"replay": {"rate_tolerance_updates": 80.0}}
    assert policy_lag(saved) == PolicyLag(tolerance=80.0, prefetch=3, queue=2, bound=-1)
    assert policy_lag({}) == DEFAULT_LAG  # written by hand: the defaults
    assert energy_epsilon({"task": {"env_version": "v4"}}) == 1e-6
    assert energy_epsilon({"task": {"env_version": "v4"}, "energy": {"epsilon": None}}) == 1e-3
