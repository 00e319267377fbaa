"""The one configuration tree. Every default equals the paper's reference value (docs/DESIGN.md §4).

Field comments name their source: [HER-py] the public PyTorch HER code, [HER-CS] the authors'
cluster code, [EBP] Zhao & Tresp 2018, [DESIGN] our choice (docs/DESIGN.md). Overrides come
from YAML (`load_yaml`) and the CLI (`apply_overrides`, `section.field=value`); every
construction runs `__post_init__` validation, naming the field and value.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hercs.config.algorithm import (
    ClusterConfig,
    DDPGConfig,
    EnergyConfig,
    HERConfig,
    default_energy_epsilon,
)
from hercs.config.bounds import check_bounds, check_machine
from hercs.config.building import RETIRED_KEYS, StrictBoolLoader, _build, _did_you_mean
from hercs.config.checks import _check, _finite_numbers
from hercs.config.deploy import (
    LEARNER_DEVICES,
    PRECISIONS,
    VIEWER_SCHEMES,
    ActorConfig,
    LaunchConfig,
    LearnerConfig,
    SecurityConfig,
    TransportConfig,
    ViewConfig,
    endpoint_parts,
    endpoint_problem,
)
from hercs.config.replay import EVICTIONS, ReplayConfig, least_rate_tolerance
from hercs.config.sizes import episode_message_bytes, size_text
from hercs.config.task import TaskConfig
from hercs.config.tracking import TRACKERS, TrackingConfig
from hercs.config.unsaved import UNSAVED
from hercs.errors import ConfigError
from hercs.rl.methods import METHODS, Method
from hercs.rl.samplers import SamplerSettings

__all__ = [
    "EVICTIONS", "LEARNER_DEVICES", "PRECISIONS", "RETIRED_KEYS", "SCHEDULES", "TRACKERS",
    "VIEWER_SCHEMES", "ActorConfig", "ClusterConfig", "DDPGConfig", "EnergyConfig", "HERConfig",
    "HercsConfig", "LaunchConfig", "LearnerConfig", "ReplayConfig", "RunConfig",
    "SecurityConfig", "TaskConfig", "TrackingConfig", "TrainingConfig", "TransportConfig",
    "ViewConfig", "apply_overrides", "endpoint_parts", "endpoint_problem", "load_yaml",
    "save_yaml", "workers_overrides",
]
"""The sections of the tree live in six modules (this one: the run and training;
hercs.config.task: the task; hercs.config.algorithm: DDPG, HER, clusters, energy;
hercs.config.replay: the replay and its episode log; hercs.config.deploy: the processes and
how they connect; hercs.config.tracking: the experiment trackers); import them all from
here."""


RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
"""A run name: never '.', '..', hidden, absolute or nested, and ASCII only."""
@dataclass
class RunConfig:
    method: str = "her-cs"
    """Sampling method: her, her-cs, her-ebp or her-ebp-cs."""
    seed: int = 1
    """Root seed; every service and actor derives its own generator from it."""
    name: str = ""
    """Run name (key prefix hercs/<name>/ and folder runs/<name>); empty = derived at start."""
    run_dir: str = "runs"
    """Parent folder of run directories."""

    def __post_init__(self) -> None:
        _check(self.method in METHODS, "run.method", self.method, f"be one of {list(METHODS)}")
        _check(self.seed >= 0, "run.seed", self.seed, "be >= 0")
        _check(
            not self.name or RUN_NAME.fullmatch(self.name) is not None,
            "run.name",
            self.name,
            "be one safe path segment: a letter or digit, then up to 99 letters, digits, '-', "
            "'_' or '.' (it names a folder under run.run_dir and a Zenoh key chunk)",
        )

    @property
    def spec(self) -> Method:
        """What `method` does (hercs.rl.methods)."""
        return METHODS[self.method]

    @property
    def uses_clusters(self) -> bool:
        """Its sampler reads cluster labels: the run's clusterer fits models."""
        return self.spec.needs.clusters


SCHEDULES = ("async", "lockstep")


@dataclass
class TrainingConfig:
    epochs: int = 200
    """Training epochs [HER-CS paper]."""
    cycles_per_epoch: int = 50
    """Cycles per epoch [HER-py]."""
    episodes_per_cycle: int = 4
    """Episodes inserted per cycle (10,000 env steps per epoch, as the authors' runs) [DESIGN]."""
    minibatches_per_cycle: int = 40
    """DDPG updates per cycle [HER-py]; updates per episode = this / episodes_per_cycle."""
    eval_episodes: int = 20
    """Deterministic test episodes after each epoch [HER-CS paper]."""
    eval_resend_s: float = 60.0
    """An epoch's evaluation not back after this long is asked for again (`eval/request`):
    its weights or its result may have been lost while the router restarted."""
    checkpoint_every: int = 10
    """Keep the policy of every n-th epoch as `checkpoints/epoch-NNNN.pt` (0: none), besides
    `learner.pt` (latest, to resume) and `best.pt` (highest evaluation success)."""
    eval_wait_s: float = 600.0
    """How long the learner waits for the last epochs' evaluations before it gives up
    (exit 1)."""
    schedule: str = "async"
    """`async`: actors and learner run concurrently, the replay's rate limiter keeps
    updates per episode within its window (a lab's many actors; data can be a few cycles
    stale). `lockstep`: the reference's single-process alternation, exactly: cycle c's
    episodes are acted with weights version c, then its updates see them (docs/DESIGN.md
    §9.1) [DESIGN]."""
    max_policy_lag: int = field(default=3, metadata={UNSAVED: -1})
    """Asynchronous schedule: the most cycles an episode may lag the lockstep schedule (its
    cycle there minus the weights version it was acted with; Sample Factory's
    `max_policy_lag`). The replay refuses an older episode as `stale_policy` before storing
    it (nothing acknowledged is ever dropped) unless it was acted with the learner's newest
    weights, and its acks tell the actors which weights to wait for. -1: no bound (what a run
    whose saved config has no such field ran with). 3 is the most the default limiter and
    prefetch give one actor (docs/PERFORMANCE.md §2), so it holds back only actors slower than
    that (many actors, a remote host). Lockstep is lag 0 by construction and ignores this
    (docs/DESIGN.md §9.1) [DESIGN]."""

    def __post_init__(self) -> None:
        _check(self.max_policy_lag == -1 or self.max_policy_lag >= 1, "training.max_policy_lag",
               self.max_policy_lag,
               "be -1 (no bound) or >= 1 (lag 0 is training.schedule=lockstep)")
        _check(self.schedule in SCHEDULES, "training.schedule", self.schedule,
               f"be one of {', '.join(SCHEDULES)}")
        for name in ("epochs", "cycles_per_epoch", "episodes_per_cycle",
                     "minibatches_per_cycle", "eval_episodes"):
            _check(getattr(self, name) >= 1, f"training.{name}", getattr(self, name), "be >= 1")
        _check(self.checkpoint_every >= 0, "training.checkpoint_every", self.checkpoint_every,
               "be >= 0 (0: no periodic policy files)")
        for name in ("eval_resend_s", "eval_wait_s"):
            value = getattr(self, name)
            _check(math.isfinite(value) and value > 0, f"training.{name}", value,
                   "be a finite number > 0")

    @property
    def updates_per_episode(self) -> float:
        return self.minibatches_per_cycle / self.episodes_per_cycle

    @property
    def episodes_per_epoch(self) -> int:
        return self.cycles_per_epoch * self.episodes_per_cycle


@dataclass
class HercsConfig:
    run: RunConfig = field(default_factory=RunConfig)
    task: TaskConfig = field(default_factory=TaskConfig)
    ddpg: DDPGConfig = field(default_factory=DDPGConfig)
    her: HERConfig = field(default_factory=HERConfig)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    energy: EnergyConfig = field(default_factory=EnergyConfig)
    training: TrainingConfig = field(default_factory=TrainingConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    actor: ActorConfig = field(default_factory=ActorConfig)
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    launch: LaunchConfig = field(default_factory=LaunchConfig)
    transport: TransportConfig = field(default_factory=TransportConfig)
    security: SecurityConfig = field(default_factory=SecurityConfig)
    view: ViewConfig = field(default_factory=ViewConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)

    def __post_init__(self) -> None:
        _finite_numbers(self)  # first: the checks below compare values
        spec = self.task.spec
        energyless = [m for m, row in METHODS.items() if not row.needs.energy]
        _check(spec.energy != "none" or not self.run.spec.needs.energy, "run.method",
               self.run.method, f"be one of {energyless} on {spec.name}: it has no trajectory "
               "energy for the sampler to read (hercs.rl.task_registry.ENERGIES; the Fetch and "
               "hand tasks have one)")
        _check(self.replay.buffer_transitions >= spec.episode_steps, "replay.buffer_transitions",
               self.replay.buffer_transitions, f"hold at least one episode ({spec.episode_steps})")
        _check(not (self.training.schedule == "lockstep" and self.replay.free_run),
               "replay.free_run", self.replay.free_run,
               "be false with training.schedule lockstep (lockstep admits by cycle)")
        # The replay's rate limiter needs a window wider than one request plus one insert, or
        # inserts and samples could both wait forever; checked here too so that `hercs up`
        # refuses the run before it starts any service.
        least = least_rate_tolerance(max_request=self.training.minibatches_per_cycle,
                                     samples_per_insert=self.training.updates_per_episode)
        _check(self.training.schedule == "lockstep" or self.replay.free_run
               or self.replay.rate_tolerance_updates >= least,
               "replay.rate_tolerance_updates", self.replay.rate_tolerance_updates,
               f"be at least (training.minibatches_per_cycle + updates per episode)/2 = "
               f"{least:g}, or inserts and samples could both wait forever")
        check_bounds(self)  # the upper bound of every numeric field (hercs.config.bounds)
        episode = episode_message_bytes(spec)
        _check(episode <= self.replay.max_message_bytes, "replay.max_message_bytes",
               self.replay.max_message_bytes,
               f"hold one episode of {spec.name} ({spec.episode_steps} steps: a "
               f"{size_text(episode)} Episode message), or the replay refuses every insert")

    @property
    def capacity_episodes(self) -> int:
        return self.replay.buffer_transitions // self.task.spec.episode_steps

    @property
    def energy_epsilon(self) -> float:
        """energy.epsilon, or task.env_version's default where it is unset."""
        epsilon = self.energy.epsilon
        return default_energy_epsilon(self.task.env_version) if epsilon is None else epsilon

    @property
    def sampler_settings(self) -> SamplerSettings:
        """What the run's episode sampler is built from (hercs.rl.methods.make_sampler)."""
        return SamplerSettings(
            k=self.cluster.k, small_cluster_repeat=self.cluster.small_cluster_repeat,
            share_rule=self.cluster.share_rule, epsilon=self.energy_epsilon,
            exponent=self.energy.exponent, cluster_fill=self.energy.cluster_fill)

    def resolved(self) -> HercsConfig:
        """This config with the defaults that depend on another field written out
        (energy.epsilon): what a run saves and gives its services, so that a later change
        of such a default never changes a run already made."""
        return dataclasses.replace(
            self, energy=dataclasses.replace(self.energy, epsilon=self.energy_epsilon))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> HercsConfig:
        return _build(cls, data, "")


def apply_overrides(config: HercsConfig, overrides: list[str]) -> HercsConfig:
    """Return a new config with `section.field=value` overrides applied and validated.

    Values are parsed as YAML scalars (so `true`, `1e-3`, `[a, b]` work); a string field takes
    the text as it is. Then as `with_values`, which holds the result to this machine.
    """
    values: dict[str, Any] = {}
    shown: dict[str, str] = {}
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or "." not in key:
            raise ConfigError(
                f"override {item!r}: must look like section.field=value, e.g. ddpg.lr_actor=1e-3"
            )
        key = key.strip()
        shown[key] = f"override {item!r}"
        section, _, name = key.partition(".")
        current = getattr(getattr(config, section, None), name, None)
        if isinstance(current, str):
            # A string field takes the text as it is, so a run named "007" stays a string.
            # (The field's type, not the value an earlier override left: "1e-5" is a string
            # to YAML, and a later override of the same number field is still a number.)
            values[key] = raw
            continue
        try:
            values[key] = yaml.load(raw, Loader=StrictBoolLoader) if raw.strip() else ""
        except yaml.YAMLError as exc:
            raise ConfigError(f"override {item!r}: value is not valid YAML ({exc})") from None
    return with_values(config, values, shown=shown)


def with_values(config: HercsConfig, values: Mapping[str, Any], *,
                shown: Mapping[str, str] | None = None) -> HercsConfig:
    """Return a new config with each `"section.field": value` set (typed Python values, as
    `hercs.up(overrides={...})` gives them), validated as a whole.

    This is how every `hercs` command and `hercs.up()` builds the config it runs here, so the
    result is also held to what this machine can hold (`hercs.config.bounds.check_machine`:
    its memory and CPUs); a config built otherwise (`HercsConfig(...)`, `from_dict`,
    `load_yaml`) may describe a run held elsewhere and is held only to the bounds of any
    machine. An unknown section or field is refused by name, with the nearest known one
    (`shown`: how an error names a key's item, e.g. "override 'ddpg.lr=1'").
    """
    data = config.to_dict()
    for key, value in values.items():
        key = str(key).strip()
        section, dot, name = key.partition(".")
        item = (shown or {}).get(key) or f"{key!r} (= {value!r})"
        if not dot:
            raise ConfigError(f"{item}: the key must look like section.field, e.g. "
                              "ddpg.lr_actor")
        if section not in data or not isinstance(data[section], dict):
            raise ConfigError(f"{item}: unknown section {section!r};"
                              f"{_did_you_mean(section, data)} known: {sorted(data)}")
        if name not in data[section]:
            raise ConfigError(f"{item}: unknown field {key!r};"
                              f"{_did_you_mean(name, data[section], section + '.')} known in "
                              f"{section}: {sorted(data[section])} (`hercs config` prints "
                              "every field with its value)")
        data[section][name] = list(value) if isinstance(value, tuple) else value
    result = HercsConfig.from_dict(data)
    check_machine(result)
    return result


def workers_overrides(config: HercsConfig, workers: int) -> list[str]:
    """The reference's N-worker setting as overrides of `config`: N× episodes per cycle, N×
    the minibatch, N actors.

    In the reference code each of N MPI workers collects its own episodes every cycle and runs
    the cycle's updates on its own minibatch, and the gradients are averaged over the workers
    before every Adam step: together, N× the episodes per cycle and (up to each worker
    sampling from its own buffer) one update on N× the minibatch. The number of updates per
    cycle, and so the updates per episode, is unchanged per worker: a learner that runs N×
    larger updates as fast as it ran one (a GPU) can use N× the actors [DESIGN]."""
    if workers < 1:
        raise ConfigError(f"--workers: got {workers}, must be >= 1")
    return [f"training.episodes_per_cycle={config.training.episodes_per_cycle * workers}",
            f"ddpg.batch_size={config.ddpg.batch_size * workers}",
            f"actor.num_actors={workers}"]


def load_yaml(path: str | Path) -> HercsConfig:
    """Load a (possibly partial) config; missing fields keep their defaults. Booleans are
    YAML 1.2's (`StrictBoolLoader`); every error names the file."""
    name = f"config file {str(path)!r}"
    start = "`hercs config -o FILE` writes the full default config to start from"
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise ConfigError(f"{name}: no such file; give the path of a YAML config ({start})"
                          ) from None
    except IsADirectoryError:
        raise ConfigError(f"{name}: is a folder, not a YAML file (a run folder's config is "
                          "its config.yaml; `hercs up --resume RUN` continues a run)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{name}: cannot read it ({exc})") from None
    try:
        data = yaml.load(text, Loader=StrictBoolLoader) or {}
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f", line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        context, begun = getattr(exc, "context", None), getattr(exc, "context_mark", None)
        if context and begun is not None:
            problem += f", {context} that begins at line {begun.line + 1}, column " \
                       f"{begun.column + 1}"
        raise ConfigError(f"{name}{at}: not valid YAML ({problem}); fix the file there "
                          f"({start})") from None
    merged = HercsConfig().to_dict()
    if not isinstance(data, dict):
        raise ConfigError(f"{name}: must hold a mapping of sections (e.g. `ddpg:` with "
                          f"`lr_actor: 0.001` under it), got {data!r}")
    for section, values in data.items():
        if section not in merged:
            raise ConfigError(f"{name}: unknown section {section!r};"
                              f"{_did_you_mean(str(section), merged)} known: {sorted(merged)}")
        if not isinstance(values, dict):
            raise ConfigError(f"{name}: section {section!r} must be a "
                              f"mapping, got {values!r}")
        for key in values:
            if key not in merged[section] and f"{section}.{key}" not in RETIRED_KEYS:
                raise ConfigError(
                    f"{name}: unknown key {f'{section}.{key}'!r};"
                    f"{_did_you_mean(str(key), merged[section], section + '.')} known in "
                    f"{section}: {sorted(merged[section])}")
        merged[section].update(values)
    try:
        return HercsConfig.from_dict(merged)
    except ConfigError as exc:
        raise ConfigError(f"{name}: {exc}") from None


def save_yaml(config: HercsConfig, path: str | Path) -> None:
    """Write the full resolved config (every field, defaults included)."""
    Path(path).write_text(yaml.safe_dump(config.resolved().to_dict(), sort_keys=False))
