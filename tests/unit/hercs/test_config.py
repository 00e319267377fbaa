"""Defaults equal docs/DESIGN.md §4; overrides and YAML round trip; bad values name the field."""

import dataclasses
from pathlib import Path

import pytest

from hercs.config import HercsConfig, apply_overrides, load_yaml, save_yaml
from hercs.errors import ConfigError
from hercs.rl.task_registry import task_spec
from hercs.run.rundir import RunDir


def test_defaults_are_the_paper_reference_values() -> None:
    c = HercsConfig()
    assert (c.ddpg.hidden_size, c.ddpg.hidden_layers) == (256, 3)
    assert (c.ddpg.lr_actor, c.ddpg.lr_critic, c.ddpg.gamma, c.ddpg.polyak) == (
        1e-3, 1e-3, 0.98, 0.95)
    assert (c.ddpg.action_l2, c.ddpg.batch_size, c.ddpg.noise_eps, c.ddpg.random_eps) == (
        1.0, 256, 0.2, 0.3)
    assert (c.ddpg.clip_obs, c.ddpg.norm_clip, c.ddpg.norm_eps) == (200.0, 5.0, 0.01)
    assert c.her.replay_k == 4 and c.her.future_p == pytest.approx(0.8)
    assert (c.training.cycles_per_epoch, c.training.episodes_per_cycle,
            c.training.minibatches_per_cycle, c.training.epochs,
            c.training.eval_episodes) == (50, 4, 40, 200, 20)
    assert c.training.updates_per_episode == 10.0
    assert c.replay.buffer_transitions == 1_000_000 and c.capacity_episodes == 20_000
    # the log keeps what resume needs, in segments of a quarter buffer (docs/DESIGN.md §6)
    assert (c.replay.log_max_bytes, c.replay.log_segment_episodes(c.capacity_episodes)) == (
        0, 5_000)
    assert (c.cluster.k, c.cluster.fgb_size, c.cluster.small_cluster_repeat) == (8, 150, 4)
    assert c.task.spec.distance_threshold == 0.05, "success and failure: the Fetch radius"
    assert c.energy.clip_energy == 0.5 and (c.energy.delta_t, c.energy.gravity) == (0.04, 9.81)


def test_overrides_are_typed() -> None:
    c = apply_overrides(HercsConfig(), ["ddpg.lr_actor=5e-4", "replay.buffer_transitions=1e5",
                                        "replay.free_run=true", "run.name=007",
                                        "transport.connect=[tcp/10.0.0.1:7447]"])
    assert c.ddpg.lr_actor == 5e-4
    assert c.replay.buffer_transitions == 100_000 and isinstance(c.replay.buffer_transitions, int)
    assert c.replay.free_run is True
    assert c.run.name == "007"
    assert c.transport.connect == ["tcp/10.0.0.1:7447"]


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("ddpg.gamma=1.0", "ddpg.gamma: got 1.0"),
        ("ddpg.batch_size=0", "ddpg.batch_size: got 0"),
        ("ddpg.batch_size=2.5", "ddpg.batch_size: got 2.5, must be an integer"),
        ("ddpg.clip_return=maybe", "ddpg.clip_return: got 'maybe', must be true or false"),
        ("run.method=her-xx", "run.method: got 'her-xx'"),
        ("task.name=ant", "task.name: got 'ant'"),
        ("task.env_version=v2", "task.env_version: got 'v2', must be one of ['v4', 'v1']"),
        ("cluster.fgb_size=4", "cluster.fgb_size: got 4, must be >= k=8"),
        ("energy.w_kinetic=-1", "energy.w_kinetic: got -1.0, must be >= 0"),
        ("training.max_policy_lag=0", "training.max_policy_lag: got 0, must be -1 (no bound) "
                                      "or >= 1 (lag 0 is training.schedule=lockstep)"),
        ("learner.prefetch_depth=-1", "learner.prefetch_depth: got -1, must be >= 0"),
        ("actor.insert_queue=-2", "actor.insert_queue: got -2, must be >= 0"),
        ("task.weld_torquescale=0", "task.weld_torquescale: got 0.0, must be a finite number > 0"),
        ("ddpg.lr=1", "unknown field 'ddpg.lr'"),
        ("nosuch.x=1", "unknown section 'nosuch'"),
        ("gamma=0.9", "must look like section.field=value"),
        ("run.name=a/b", "run.name: got 'a/b'"),
        ("run.name=..", "run.name: got '..', must be one safe path segment"),
        ("run.name=.hidden", "run.name: got '.hidden'"),
        ("transport.connect=[localhost]", "transport.connect: got 'localhost'"),
        ("transport.listen=[tcp/0.0.0.0:70000]", "must have a port in 0..65535"),
        ("transport.connect=[tcp:7447]", "must be a Zenoh endpoint PROTOCOL/HOST:PORT"),
        ("energy.clip_energy=-1", "energy.clip_energy: got -1.0, must be > 0"),
        ("replay.waiting_inserts_per_actor=-1",
         "replay.waiting_inserts_per_actor: got -1, must be >= 0 (0: arrival order, no bound)"),
        ("view.episode_every=-1", "view.episode_every: got -1, must be >= 0"),
        ("view.viewer=http://host:9876", "view.viewer: got 'http://host:9876', must be 'spawn'"),
        ("view.save=run.txt", "view.save: got 'run.txt', must be '' or a path ending in .rrd"),
        ("replay.log_max_bytes=-2", "replay.log_max_bytes: got -2, must be -1 (keep the whole "
                                    "log), 0 (keep only what resume needs) or a size in bytes"),
        ("replay.log_segments_per_buffer=0", "replay.log_segments_per_buffer: got 0, must be "
                                             ">= 1"),
        ("transport.cut_off_s=5", "transport.cut_off_s: got 5.0, must be 0 (never) or a "
                                  "finite number >= 10"),
    ],
    ids=["gamma", "batch0", "batch-float", "bool", "method", "task", "env-version", "fgb",
         "energy-weight",
         "max-policy-lag-0", "prefetch-negative", "insert-queue-negative", "torquescale-0",
         "unknown-field",
         "unknown-section", "no-section", "run-name", "run-name-dotdot", "run-name-hidden",
         "endpoint", "endpoint-port", "endpoint-no-slash", "clip-energy", "waiting-inserts",
         "view-every", "view-url", "view-save", "log-max-bytes", "log-segments",
         "cut-off-below-lease"],
)
def test_bad_values_are_refused_with_the_field_named(override: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        apply_overrides(HercsConfig(), [override])
    assert message in str(err.value)


def test_yaml_round_trip(tmp_path: Path) -> None:
    c = apply_overrides(HercsConfig(), ["task.name=pick", "run.method=her-ebp-cs",
                                        "cluster.k=4", "training.epochs=3"])
    save_yaml(c, RunDir(tmp_path).config)
    assert load_yaml(RunDir(tmp_path).config) == c.resolved()
    assert c.energy.epsilon is None and load_yaml(RunDir(tmp_path).config).energy.epsilon == 1e-3


def test_energy_epsilon_defaults_to_its_simulators_and_a_run_saves_the_value() -> None:
    """ε unset is the simulator's: 1e-3 on MuJoCo 3 (v4), 1e-6 on the authors' v1, whose
    trembling cube has that floor of its own (docs/DESIGN.md §9.3). It follows an override of
    the env version made after the default, a value set by hand wins, and a saved config
    holds the number, so a later change of the rule never changes a run already made."""
    assert HercsConfig().energy.epsilon is None
    assert HercsConfig().energy_epsilon == 1e-3
    v1 = apply_overrides(HercsConfig(), ["task.env_version=v1"])
    assert v1.energy_epsilon == 1e-6 and v1.resolved().energy.epsilon == 1e-6
    assert apply_overrides(HercsConfig(), ["energy.epsilon=2e-4"]).energy_epsilon == 2e-4
    assert apply_overrides(v1, ["energy.epsilon=1e-3"]).energy_epsilon == 1e-3
    back = apply_overrides(HercsConfig(), ["energy.epsilon=1e-5", "energy.epsilon=null"])
    assert back.energy.epsilon is None and back.energy_epsilon == 1e-3
    for bad, message in (("0", "energy.epsilon: got 0.0, must be > 0"),
                         ("abc", "energy.epsilon: got 'abc', must be a number"),
                         ("[1]", "must be a number")):
        with pytest.raises(ConfigError) as err:
            apply_overrides(HercsConfig(), [f"energy.epsilon={bad}"])
        assert message in str(err.value)


def test_partial_yaml_keeps_defaults_and_rejects_unknown(tmp_path: Path) -> None:
    (tmp_path / "a.yaml").write_text("ddpg:\n  lr_actor: 0.0005\n")
    c = load_yaml(tmp_path / "a.yaml")
    assert c.ddpg.lr_actor == 0.0005 and c.ddpg.gamma == 0.98
    (tmp_path / "b.yaml").write_text("ddpg:\n  lr_actr: 0.0005\n")
    with pytest.raises(ConfigError, match="unknown key"):
        load_yaml(tmp_path / "b.yaml")
    (tmp_path / "c.yaml").write_text("- not a mapping\n")
    with pytest.raises(ConfigError, match="must hold a mapping"):
        load_yaml(tmp_path / "c.yaml")


def test_a_saved_config_with_a_retired_key_still_loads(tmp_path: Path) -> None:
    """Configs written before `cluster.failure_threshold` was retired (the failure rule is the
    task's own) load, and the key is dropped; other unknown keys are still refused."""
    data = HercsConfig().to_dict()
    data["cluster"]["failure_threshold"] = 0.05
    assert HercsConfig.from_dict(data) == HercsConfig()
    data["cluster"]["no_such_key"] = 1
    with pytest.raises(ConfigError, match="no_such_key"):
        HercsConfig.from_dict(data)


@pytest.mark.parametrize("version", ["v4", "v1"])
def test_the_env_version_picks_the_env_every_factory_makes(version: str) -> None:
    """Fetch*-v1 and Fetch*-v4 differ in their env id only: the shapes the wire, the replay and
    the networks are built from are the same."""
    c = apply_overrides(HercsConfig(), ["task.name=pick", f"task.env_version={version}"])
    assert c.task.spec.env_id == f"FetchPickAndPlace-{version}"
    default = HercsConfig().task
    assert default.env_version == "v4" and default.spec.env_id == "FetchPush-v4"
    for name in ("reach", "push", "pick", "slide"):
        v1, v4 = task_spec(name, "v1"), task_spec(name, "v4")
        assert dataclasses.replace(v1, env_version="v4") == v4


def test_the_weld_torquescale_is_a_v4_setting() -> None:
    with pytest.raises(ConfigError, match=r"task\.weld_torquescale: got 4\.0, must be 1 with "
                                          r"task\.env_version v1"):
        apply_overrides(HercsConfig(), ["task.env_version=v1", "task.weld_torquescale=4"])
    spec = apply_overrides(HercsConfig(), ["task.weld_torquescale=4"]).task.spec
    assert (spec.env_id, spec.weld_torquescale) == ("FetchPush-v4", 4.0)


def test_a_rate_window_too_narrow_for_the_limiter_is_refused_before_any_service_starts() -> None:
    # 40 updates per cycle of 2 episodes: one request (40) plus one insert (20), halved, is 30
    with pytest.raises(ConfigError, match=r"replay\.rate_tolerance_updates: got 25\.0, must be "
                                          r"at least .* = 30, or inserts and samples could both "
                                          r"wait forever"):
        apply_overrides(HercsConfig(), ["training.episodes_per_cycle=2",
                                        "replay.rate_tolerance_updates=25"])
    # the window does not matter where the limiter does not hold anything back
    for mode in ("replay.free_run=true", "training.schedule=lockstep"):
        c = apply_overrides(HercsConfig(), ["training.episodes_per_cycle=2",
                                            "replay.rate_tolerance_updates=25", mode])
        assert c.replay.rate_tolerance_updates == 25


def _float_fields(config: object, where: str = "") -> list[str]:
    """The dotted names of every float field of the tree (`float | None` included)."""
    names = []
    for item in dataclasses.fields(config):  # type: ignore[arg-type]
        value, path = getattr(config, item.name), f"{where}{item.name}"
        if dataclasses.is_dataclass(value):
            names += _float_fields(value, f"{path}.")
        elif "float" in str(item.type):
            names.append(path)
    return names


FLOAT_FIELDS = _float_fields(HercsConfig())


@pytest.mark.parametrize("value",
                         ["inf", "-inf", "nan", ".inf", ".nan", "1e400", "1" + "0" * 400],
                         ids=["inf", "minus-inf", "nan", "yaml-inf", "yaml-nan", "1e400",
                              "huge-int"])
def test_no_float_field_takes_a_number_that_is_not_finite(value: str) -> None:
    """One mechanism covers every float field, present and future (an infinite learning rate
    once passed, diverged at the first update and left the run standing still)."""
    assert {"ddpg.lr_critic", "energy.epsilon", "launch.stall_factor"} <= set(FLOAT_FIELDS)
    for name in FLOAT_FIELDS:
        with pytest.raises(ConfigError) as err:
            apply_overrides(HercsConfig(), [f"{name}={value}"])
        assert str(err.value).startswith(f"{name}: got "), str(err.value)
        assert "must be a finite number" in str(err.value)


def test_a_yaml_file_with_an_infinite_value_is_refused_naming_the_file_and_field(
        tmp_path: Path) -> None:
    (tmp_path / "run.yaml").write_text("ddpg:\n  lr_actor: .inf\n")
    with pytest.raises(ConfigError, match=r"run\.yaml'?: ddpg\.lr_actor: got inf, must be a "
                                          r"finite number"):
        load_yaml(tmp_path / "run.yaml")


def test_a_tree_built_in_code_is_walked_too() -> None:
    """A section constructed directly (the Python API) is checked when the tree is built,
    fields without a bound of their own included."""
    from hercs.config import DDPGConfig, LaunchConfig

    with pytest.raises(ConfigError, match=r"^ddpg\.action_l2: got inf, must be a finite"):
        HercsConfig(ddpg=DDPGConfig(action_l2=float("inf")))
    with pytest.raises(ConfigError, match=r"^launch\.restart_backoff_s: got nan"):
        HercsConfig(launch=LaunchConfig(restart_backoff_s=float("nan")))


@pytest.mark.parametrize(
    ("override", "message"),
    [("ddpg.lr_critic=1e300", "ddpg.lr_critic: got 1e+300, must lie in (0, 1]"),
     ("ddpg.lr_actor=1.5", "ddpg.lr_actor: got 1.5, must lie in (0, 1]"),
     ("ddpg.lr_actor=0", "ddpg.lr_actor: got 0.0, must lie in (0, 1]"),
     ("ddpg.polyak=1.01", "ddpg.polyak: got 1.01, must lie in [0, 1]"),
     ("ddpg.gamma=0", "ddpg.gamma: got 0.0, must lie in (0, 1)"),
     ("launch.stall_factor=1.5", "launch.stall_factor: got 1.5, must be 0 (never) or >= 2"),
     ("launch.stall_factor=-1", "launch.stall_factor: got -1.0, must be 0 (never) or >= 2")],
    ids=["lr-huge", "lr-above-1", "lr-0", "polyak", "gamma-0", "stall-factor-1.5",
         "stall-factor-negative"],
)
def test_bounded_numbers_are_refused_outside_their_bounds(override: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        apply_overrides(HercsConfig(), [override])
    assert message in str(err.value)
    for fine in ("ddpg.lr_critic=1", "launch.stall_factor=0", "launch.stall_factor=2"):
        assert apply_overrides(HercsConfig(), [fine])
