"""Every numeric field of the config has an upper bound (hercs.config.bounds), named in the
refusal with why; a value the machine cannot hold is refused before anything starts: `hercs
up` exits 2 at once and makes no folder (issue 57, item 2: the audit's values)."""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import subprocess
import sys
import time
import typing
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hercs.apps.cli.main import main
from hercs.config import HercsConfig, apply_overrides, load_yaml
from hercs.config.bounds import BOUNDS, MACHINE_BOUNDS, check_machine
from hercs.config.limits import MAX_STALL_S
from hercs.config.sizes import Machine, stored_episode_bytes, this_machine
from hercs.errors import ConfigError
from hercs.replay_service.store import EpisodeStore

REPO = Path(__file__).resolve().parents[3]
REFUSED_S = 30.0
"""A refused `hercs up` imports hercs and parses its flags (under a second here, without
torch); 30 s holds on a loaded machine's cold start."""
REFUSAL_BYTES = 64 << 20
"""The most the refusal itself may allocate (tracemalloc's peak, imports done): what the audit
guards against is a check that builds what the value asks for (a 10^15-transition buffer, a
10^9-wide layer) before refusing it; a check that only compares numbers allocates kilobytes.
Bytes, not seconds, so that the bound holds on a machine of any speed."""

AUDIT = [
    pytest.param("training.epochs=1e300", "must be an integer: a float past 2**53", None,
                 id="epochs-as-float"),
    pytest.param(f"training.epochs={10**300}", "metrics.csv records counts as doubles", BOUNDS,
                 id="epochs-as-digits"),
    pytest.param("replay.buffer_transitions=1000000000000000", "of storage", BOUNDS,
                 id="buffer-transitions"),
    pytest.param("ddpg.batch_size=1000000000", "it would refuse every request", BOUNDS,
                 id="batch-size"),
    pytest.param("ddpg.hidden_size=1000000000", "Weights message", BOUNDS, id="hidden-size"),
    pytest.param(f"ddpg.hidden_layers={10**26}", "Weights message", BOUNDS,
                 id="hidden-layers"),
    pytest.param("replay.insert_workers=1000000", "per CPU of this machine's", MACHINE_BOUNDS,
                 id="insert-workers"),
    pytest.param("actor.insert_timeout_s=1e300", "longer than a day", BOUNDS,
                 id="insert-timeout"),
    pytest.param("training.eval_episodes=1e9", "training.eval_wait_s", BOUNDS,
                 id="eval-episodes"),
]
"""The audit's values: the override, what the refusal says, and which table's bound it names
(None: refused as no integer before any bound)."""


def _refusal(override: str) -> str:
    with pytest.raises(ConfigError) as err:
        apply_overrides(HercsConfig(), [override])
    return str(err.value)


def _stated_bound(override: str, table: dict[str, Any] | None) -> str | None:
    """What the refusal must say of the bound, from the field's rule itself."""
    if table is None:
        return None
    field = override.partition("=")[0]
    config = HercsConfig()
    if table is MACHINE_BOUNDS:
        most = MACHINE_BOUNDS[field](config, config.task.spec, this_machine()).most
        return f"must be <= {int(most)} here: "
    most = BOUNDS[field](config, config.task.spec).most
    return f"must be <= {int(most)}: " if float(most).is_integer() else f"must be <= {most:g}: "


@pytest.mark.parametrize(("override", "why", "table"), AUDIT)
def test_the_audits_values_are_refused_by_hercs_up_at_once_and_make_no_folder(
        tmp_path: Path, override: str, why: str, table: dict[str, Any] | None) -> None:
    runs = tmp_path / "runs"
    started = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "hercs.apps.cli", "up", "--set", override,
         "--run-dir", str(runs)],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)  # its own group: a run it should not have started dies whole
    try:
        out, err = proc.communicate(timeout=REFUSED_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail(f"hercs up --set {override} was not refused within {REFUSED_S:g} s")
    took = time.monotonic() - started
    print(f"hercs up --set {override[:40]}: exit {proc.returncode} in {took:.2f} s")
    field = override.partition("=")[0]
    assert proc.returncode == 2, err
    assert err == f"hercs up: invalid configuration: {_refusal(override)}\n"
    assert err.startswith(f"hercs up: invalid configuration: {field}: got ")
    assert why in err
    bound = _stated_bound(override, table)
    assert bound is None or bound in err, err
    assert out == ""
    assert list(tmp_path.iterdir()) == [], "nothing was started or written"
    assert took < REFUSED_S


@pytest.mark.parametrize(("override", "why", "table"), AUDIT)
def test_the_refusal_itself_builds_nothing_the_value_asks_for(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        override: str, why: str, table: object) -> None:
    import tracemalloc

    import hercs.apps.launch.launcher as launcher

    def started(*args: Any, **kwargs: Any) -> int:
        raise AssertionError("hercs up started a run")
    monkeypatch.setattr(launcher, "run_up", started)
    main(["up", "--set", "ddpg.gamma=1", "--run-dir", str(tmp_path / "runs")])  # imports
    tracemalloc.start()
    try:
        code = main(["up", "--set", override, "--run-dir", str(tmp_path / "runs")])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    err = capsys.readouterr().err
    print(f"refusing {override[:40]} in-process: {peak / 1024:.0f} KiB at most")
    assert code == 2
    assert why in err
    assert peak < REFUSAL_BYTES
    assert not (tmp_path / "runs").exists()


# -- the bounds themselves ---------------------------------------------------------------------

def _numeric_fields() -> list[str]:
    fields = []
    for section in dataclasses.fields(HercsConfig):
        cls = typing.get_type_hints(HercsConfig)[section.name]
        for name, hint in typing.get_type_hints(cls).items():
            if hint in (int, float) or set(typing.get_args(hint)) == {float, type(None)}:
                fields.append(f"{section.name}.{name}")
    return fields


def test_every_numeric_field_has_an_upper_bound_with_its_derivation() -> None:
    fields = _numeric_fields()
    assert len(fields) > 50
    assert sorted(set(fields) - set(BOUNDS)) == [], "a numeric field without a bound"
    assert set(MACHINE_BOUNDS) <= set(BOUNDS), "a machine bound without one for any machine"
    for field, rule in [*BOUNDS.items(), *MACHINE_BOUNDS.items()]:
        assert rule.__doc__ and len(rule.__doc__) > 10, f"{field}: say where the bound comes from"


BASE: dict[str, list[str]] = {
    # a bound that moves another's: keep the other within its own at this one's bound
    "ddpg.norm_eps": ["ddpg.norm_clip=1"],
    "training.minibatches_per_cycle": ["replay.rate_tolerance_updates=1000"],
    "task.episode_steps": ["training.eval_episodes=1"],
    "cluster.k": ["cluster.fgb_size=1000"],
}
SECTION_CHECKED = {"ddpg.lr_actor", "ddpg.lr_critic", "ddpg.gamma", "ddpg.polyak",
                   "ddpg.random_eps", "actor.envs_per_process"}
"""Bounds checked with the lower bound in the field's section, with its message."""


def _build(changes: dict[str, Any]) -> HercsConfig:
    """The default config with `changes` (typed values), held to the bounds of any machine."""
    data = HercsConfig().to_dict()
    for field, value in changes.items():
        section, _, name = field.partition(".")
        data[section][name] = value
    return HercsConfig.from_dict(data)


def _base(field: str) -> dict[str, Any]:
    return {key: yaml.safe_load(raw) for key, _, raw in
            (item.partition("=") for item in BASE.get(field, []))}


def _past(most: float, hint: type) -> float:
    return int(most) + 1 if hint is int else math.nextafter(most, math.inf)


def _hint(field: str) -> type:
    section, _, name = field.partition(".")
    cls = typing.get_type_hints(HercsConfig)[section]
    hint = typing.get_type_hints(cls)[name]
    return int if hint is int else float


@pytest.mark.parametrize("field", sorted(BOUNDS), ids=sorted(BOUNDS))
def test_a_value_at_the_bound_passes_and_one_past_it_is_refused_naming_the_bound(
        field: str) -> None:
    base = _build(_base(field))
    most = BOUNDS[field](base, base.task.spec).most
    hint = _hint(field)
    at = int(most) if hint is int else float(most)
    config = _build({**_base(field), field: at})
    assert getattr(getattr(config, field.split(".")[0]), field.split(".")[1]) == at
    with pytest.raises(ConfigError) as err:
        _build({**_base(field), field: _past(at, hint)})
    message = str(err.value)
    assert message.startswith(f"{field}: got "), message
    if field not in SECTION_CHECKED:
        assert ", must be <= " in message and ": " in message.partition(" must be <= ")[2]


FAKE = Machine(memory_bytes=8 * 2**30, cpus=4)
MACHINE_BASE: dict[str, dict[str, Any]] = {
    # a wider wire, so that the machine's memory is what bounds the networks
    "ddpg.hidden_size": {"replay.max_message_bytes": 2**31 - 1},
    "ddpg.hidden_layers": {"replay.max_message_bytes": 2**31 - 1},
}


@pytest.mark.parametrize("field", sorted(MACHINE_BOUNDS), ids=sorted(MACHINE_BOUNDS))
def test_a_value_this_machine_cannot_hold_is_refused_and_one_it_can_passes(field: str) -> None:
    extra = MACHINE_BASE.get(field, {})
    base = _build(extra)
    most = int(MACHINE_BOUNDS[field](base, base.task.spec, FAKE).most)
    assert most < BOUNDS[field](base, base.task.spec).most, "the machine bounds it, not the wire"
    check_machine(_build({**extra, field: most}), FAKE)
    past = _build({**extra, field: most + 1})
    with pytest.raises(ConfigError) as err:
        check_machine(past, FAKE)
    assert str(err.value).startswith(f"{field}: got {most + 1}, must be <= {most} here: ")


def test_the_machine_bound_names_the_memory_and_the_storage() -> None:
    big = _build({"replay.buffer_transitions": 10**9})
    with pytest.raises(ConfigError) as err:
        check_machine(big, FAKE)
    assert str(err.value) == (
        "replay.buffer_transitions: got 1000000000, must be <= 58658399 here: 136 GiB of "
        "storage (7.2 KiB per episode of 50 steps) against this machine's 8.0 GiB of memory")


def test_a_config_read_elsewhere_is_not_held_to_this_machine() -> None:
    """A run folder's config, a checkpoint's or one a replay serves describes a run held
    where it runs: only `apply_overrides`, which builds what a command runs here, checks the
    machine."""
    here = this_machine()
    too_big = int(MACHINE_BOUNDS["replay.buffer_transitions"](
        HercsConfig(), HercsConfig().task.spec, here).most) + 1
    config = _build({"replay.buffer_transitions": too_big})
    assert config.replay.buffer_transitions == too_big
    with pytest.raises(ConfigError, match=r"replay.buffer_transitions: got \d+, must be <= "
                                          r"\d+ here: "):
        apply_overrides(config, [])


def test_the_storage_estimate_is_what_the_store_allocates() -> None:
    spec = HercsConfig().task.spec
    store = EpisodeStore(capacity_episodes=1000, spec=spec)

    def nbytes(obj: object) -> int:
        return sum(v.nbytes for v in vars(obj).values() if isinstance(v, np.ndarray))
    allocated = nbytes(store) + nbytes(store.sampling_index)
    estimated = 1000 * stored_episode_bytes(spec, clusters=0)
    assert allocated <= estimated <= 1.02 * allocated


@pytest.mark.parametrize("text", ["1e300", "1.0e+300", "9.1e15"], ids=["1e300", "1.0e+300",
                                                                      "past-2**53"])
def test_an_integer_field_refuses_a_float_too_large_to_be_one_integer(
        tmp_path: Path, text: str) -> None:
    path = tmp_path / "config.yaml"
    path.write_text(f"training:\n  epochs: {text}\n")
    with pytest.raises(ConfigError, match=r"training.epochs: got .*, must be an integer: a "
                                          r"float past 2\*\*53"):
        load_yaml(path)
    assert apply_overrides(HercsConfig(), ["training.epochs=1e3"]).training.epochs == 1000


def test_the_defaults_and_every_committed_config_are_within_their_bounds() -> None:
    apply_overrides(HercsConfig(), [])
    paths = sorted([*REPO.glob("docs/results/**/config.yaml"),
                    *REPO.glob("docs/demo/*/config.yaml")])
    ours = [p for p in paths if "peer" not in (yaml.safe_load(p.read_text()) or {})]
    assert len(ours) > 100  # the others are the authors' code's runs (a `peer` section)
    for path in ours:
        apply_overrides(load_yaml(path), [])


def test_this_machine_is_read() -> None:
    here = this_machine()
    assert here.memory_bytes > 2**28 and here.cpus >= 1


def test_no_config_makes_the_stall_bound_longer_than_a_day() -> None:
    from hercs.apps.launch.stall import StallWatch, expected_first_epoch_s

    slowest = _build({"ddpg.batch_size": 6553, "ddpg.hidden_size": 1014,
                      "training.cycles_per_epoch": 1000, "training.eval_episodes": 12000})
    assert expected_first_epoch_s(slowest) * slowest.launch.stall_factor > MAX_STALL_S
    watch = StallWatch(factor=slowest.launch.stall_factor,
                       first_epoch_s=expected_first_epoch_s(slowest))
    assert watch.bound_s == MAX_STALL_S == 24 * 3600
