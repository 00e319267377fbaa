"""The one configuration tree. Every default equals the paper's reference value (docs/DESIGN.md §4).

Sources named in the field comments:
- [HER-py]  the public PyTorch HER implementation the paper builds on (DDPG+HER, arguments.py).
- [HER-CS]  the authors' code for cluster-based sampling (fgb size, k, small-cluster rule).
- [EBP]     Zhao & Tresp 2018, energy-based prioritisation (clip_energy for PickAndPlace).
- [DESIGN]  docs/DESIGN.md: our choice where the paper and the reference code are silent.

Overrides come from YAML (`load_yaml`) and the CLI (`apply_overrides` with `section.field=value`);
every construction runs `__post_init__` validation, whose messages name the field and value.
"""

from __future__ import annotations

import dataclasses
import difflib
import logging
import math
import re
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hercs.errors import ConfigError
from hercs.methods import METHODS, Method
from hercs.tasks import ENV_VERSIONS, TASKS, TaskSpec, task_spec

log = logging.getLogger(__name__)

RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
"""A run name: never '.', '..', hidden, absolute or nested, and ASCII only."""
ENDPOINT = re.compile(r"(?P<proto>tcp|udp|tls|quic|ws)/(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)"
                      r":(?P<port>[0-9]{1,5})(?:#.*)?")
"""A Zenoh locator this project uses: protocol/host:port (an IPv6 host in brackets)."""


def endpoint_problem(endpoint: object) -> str | None:
    """Why `endpoint` is not a usable Zenoh endpoint, or None."""
    if not isinstance(endpoint, str):
        return "be a string"
    match = ENDPOINT.fullmatch(endpoint)
    if match is None:
        return ("be a Zenoh endpoint PROTOCOL/HOST:PORT, e.g. 'tcp/127.0.0.1:7447' or "
                "'tls/learner.lab:7447' (protocols: tcp, udp, tls, quic, ws)")
    if not 0 <= int(match["port"]) <= 65535:
        return "have a port in 0..65535"
    return None


def endpoint_parts(endpoint: str) -> tuple[str, str, int]:
    """(protocol, host, port) of a valid endpoint (`endpoint_problem` is None)."""
    match = ENDPOINT.fullmatch(endpoint)
    if match is None:
        raise ConfigError(f"endpoint {endpoint!r}: {endpoint_problem(endpoint)}")
    return match["proto"], match["host"], int(match["port"])


def _check(cond: bool, where: str, value: object, must: str) -> None:
    if not cond:
        raise ConfigError(f"{where}: got {value!r}, must {must}")


def _positive(where: str, value: float) -> None:
    _check(value > 0, where, value, "be > 0")


def _unit_interval(where: str, value: float, *, closed: bool = True) -> None:
    ok = 0.0 <= value <= 1.0 if closed else 0.0 < value < 1.0
    _check(ok, where, value, "lie in [0, 1]" if closed else "lie in (0, 1)")


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
    tensorboard: bool = False
    """The learner also writes TensorBoard event files to runs/<name>/tensorboard/: the
    scalars of metrics.csv per epoch (`hercs up --tensorboard`)."""

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
        """What `method` does (hercs.methods)."""
        return METHODS[self.method]

    @property
    def uses_clusters(self) -> bool:
        return self.spec.cluster_balanced


@dataclass
class TaskConfig:
    name: str = "push"
    """Task preset: reach, push, pick (PickAndPlace) or slide."""
    env_version: str = "v4"
    """v4: gymnasium-robotics Fetch*-v4 on MuJoCo 3 [DESIGN]; v1: the authors' Fetch*-v1 on
    mujoco-py and MuJoCo 2.1 [HER-py] (installed by `make mujoco-py`). Same shapes, horizon
    and reward; the physics differ (docs/DESIGN.md §9)."""
    weld_torquescale: float = 1.0
    """v4 only: the torquescale of the mocap weld that moves the gripper, MuJoCo 3's
    rotational weight of the weld (1, its default). MuJoCo 2.1 has no such setting and holds
    the gripper ~10x stiffer against tilting; 4 makes v4's gripper tilt, and the pushed cube
    turn and topple, as on v1 (docs/results/env_diff.md) [DESIGN]."""

    def __post_init__(self) -> None:
        _check(self.name in TASKS, "task.name", self.name, f"be one of {sorted(TASKS)}")
        _check(self.env_version in ENV_VERSIONS, "task.env_version", self.env_version,
               f"be one of {list(ENV_VERSIONS)} (v1 is the authors' Fetch*-v1 on mujoco-py)")
        _check(math.isfinite(self.weld_torquescale) and self.weld_torquescale > 0,
               "task.weld_torquescale", self.weld_torquescale, "be a finite number > 0")
        _check(self.weld_torquescale == 1.0 or self.env_version == "v4",
               "task.weld_torquescale", self.weld_torquescale,
               "be 1 with task.env_version v1 (MuJoCo 2.1's weld has no torquescale)")

    @property
    def spec(self) -> TaskSpec:
        """The task on its environment version: what every env factory makes."""
        return task_spec(self.name, self.env_version, self.weld_torquescale)


@dataclass
class DDPGConfig:
    hidden_size: int = 256
    """Units per hidden layer of actor and critic [HER-py]."""
    hidden_layers: int = 3
    """Hidden ReLU layers of actor and critic [HER-py]."""
    lr_actor: float = 1e-3
    """Adam learning rate of the actor [HER-py]."""
    lr_critic: float = 1e-3
    """Adam learning rate of the critic [HER-py]."""
    gamma: float = 0.98
    """Discount [HER-py]."""
    polyak: float = 0.95
    """Target nets: θ' ← polyak·θ' + (1−polyak)·θ, once per cycle [HER-py]."""
    action_l2: float = 1.0
    """Weight of the actor's (a/max_action)² penalty [HER-py]."""
    clip_return: bool = True
    """Clip the critic target to [−1/(1−γ), 0] [HER-py]."""
    batch_size: int = 256
    """Transitions per minibatch [HER-py]."""
    noise_eps: float = 0.2
    """Gaussian exploration noise, times max_action [HER-py]."""
    random_eps: float = 0.3
    """Probability of a uniformly random action while exploring [HER-py]."""
    clip_obs: float = 200.0
    """Observations and goals are clipped to ±clip_obs before normalising [HER-py]."""
    norm_clip: float = 5.0
    """Normalised inputs are clipped to ±norm_clip [HER-py]."""
    norm_eps: float = 0.01
    """Floor of the normaliser's standard deviation [HER-py]."""

    def __post_init__(self) -> None:
        for name in ("hidden_size", "hidden_layers", "batch_size"):
            _check(getattr(self, name) >= 1, f"ddpg.{name}", getattr(self, name), "be >= 1")
        for name in ("lr_actor", "lr_critic", "clip_obs", "norm_clip", "norm_eps"):
            _positive(f"ddpg.{name}", getattr(self, name))
        _unit_interval("ddpg.gamma", self.gamma, closed=False)
        _unit_interval("ddpg.polyak", self.polyak)
        _unit_interval("ddpg.random_eps", self.random_eps)
        _check(self.action_l2 >= 0, "ddpg.action_l2", self.action_l2, "be >= 0")
        _check(self.noise_eps >= 0, "ddpg.noise_eps", self.noise_eps, "be >= 0")

    @property
    def clip_return_value(self) -> float:
        return 1.0 / (1.0 - self.gamma)


@dataclass
class HERConfig:
    replay_k: int = 4
    """Relabel ratio: a sampled transition gets a future goal with p = 1 − 1/(1+k) [HER-py]."""

    def __post_init__(self) -> None:
        _check(self.replay_k >= 0, "her.replay_k", self.replay_k, "be >= 0")

    @property
    def future_p(self) -> float:
        return 1.0 - 1.0 / (1.0 + self.replay_k)


@dataclass
class ClusterConfig:
    k: int = 8
    """Number of k-means clusters of failed goals [HER-CS]."""
    fgb_size: int = 150
    """Failed-goal buffer capacity; a refit happens each time it has been entirely replaced
    [HER-CS]."""
    small_cluster_repeat: int = 4
    """A cluster with fewer than share/repeat episodes contributes each member ~repeat times
    and fills the rest of its share uniformly [HER-CS]."""
    kmeans_n_init: int = 10
    """k-means restarts per refit (scikit-learn; seeded)."""

    def __post_init__(self) -> None:
        _check(self.k >= 1, "cluster.k", self.k, "be >= 1")
        _check(self.fgb_size >= self.k, "cluster.fgb_size", self.fgb_size, f"be >= k={self.k}")
        _check(self.small_cluster_repeat >= 1, "cluster.small_cluster_repeat",
               self.small_cluster_repeat, "be >= 1")
        _check(self.kmeans_n_init >= 1, "cluster.kmeans_n_init", self.kmeans_n_init, "be >= 1")


@dataclass
class EnergyConfig:
    clip_energy: float = 0.5
    """Per-transition energy clip; the reference's PickAndPlace setting, used for every task
    [EBP]."""
    mass: float = 1.0
    """Object mass m in the potential and kinetic terms [EBP]."""
    gravity: float = 9.81
    """g in the potential term m·g·(z_t − z_0) [EBP]."""
    delta_t: float = 0.04
    """Time between env steps, for velocities Δag/Δt [EBP]."""
    w_potential: float = 1.0
    """Weight of the potential energy [EBP]."""
    w_kinetic: float = 1.0
    """Weight of the kinetic energy [EBP]."""
    epsilon: float = 1e-6
    """Added to every trajectory energy so no episode has p = 0 [DESIGN]."""
    temperature: float = 0.99
    """p ∝ e^(1/(temperature + 0.01)) + ε, the reference's form: 0.99 makes the exponent 1
    (p ∝ e + ε, docs/DESIGN.md §4); the reference's default temperature 1 gives 0.990 [EBP]."""
    cluster_fill: str = "energy"
    """HER-EBP-CS inside a cluster: draw its members by energy (`energy`, our definition) or
    uniformly (`uniform`, HER-CS's draw with EBP only in the whole-buffer fills) [DESIGN]."""

    def __post_init__(self) -> None:
        for name in ("clip_energy", "mass", "gravity", "delta_t", "epsilon", "temperature"):
            _positive(f"energy.{name}", getattr(self, name))
        _check(self.cluster_fill in ("energy", "uniform"), "energy.cluster_fill",
               self.cluster_fill, "be energy or uniform")
        for name in ("w_potential", "w_kinetic"):
            _check(getattr(self, name) >= 0, f"energy.{name}", getattr(self, name), "be >= 0")

    @property
    def exponent(self) -> float:
        """The power the trajectory energies are raised to before ε is added."""
        return 1.0 / (self.temperature + 0.01)


SCHEDULES = ("async", "lockstep")
EVICTIONS = ("fifo", "random")


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
    max_policy_lag: int = 3
    """Asynchronous schedule: the most cycles an episode may lag the lockstep schedule (its
    cycle there minus the weights version it was acted with; Sample Factory's
    `max_policy_lag`). The replay refuses an older episode as `stale_policy` before storing
    it (nothing acknowledged is ever dropped) unless it was acted with the learner's newest
    weights, and its acks tell the actors which weights to wait for. -1: no bound. 3 is the
    most the default limiter and prefetch give one actor (docs/PERFORMANCE.md §2), so it holds
    back only actors slower than that (many actors, a remote host). Lockstep is lag 0 by
    construction and ignores this (docs/DESIGN.md §9.1) [DESIGN]."""

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
class ReplayConfig:
    buffer_transitions: int = 1_000_000
    """Capacity in transitions; the store holds buffer_transitions // T episodes [HER-py]."""
    min_episodes_to_sample: int = 4
    """Samples wait until this many episodes are stored (one cycle's worth) [DESIGN]."""
    rate_tolerance_updates: float = 40.0
    """How far updates may run ahead of or behind updates_per_episode × inserts, in
    minibatches (Reverb's error_buffer); one cycle's worth by default. Each cycle of it is a
    cycle of policy lag in the asynchronous schedule: 40 is the least stale setting that
    kept the epoch time of the old default (80) side by side (docs/PERFORMANCE.md §2) [DESIGN]."""
    free_run: bool = False
    """Disable the rate limiter: inserts and samples never wait [DESIGN]."""
    max_message_bytes: int = 8 * 1024 * 1024
    """Larger wire messages are rejected as oversized [DESIGN]."""
    sample_timeout_s: float = 600.0
    """How long the learner waits for one Batch (the rate limiter may hold its request while
    actors catch up) before it asks again; the replay drops a request parked longer [DESIGN]."""
    insert_workers: int = 4
    """Threads serving inserts: inserts that arrive while one group is being fsynced form the
    next group (group commit), so several workers share fsyncs [DESIGN]."""
    log_scene: bool = True
    """Also log each episode's Foxglove scene (/scene, /scene/points), off the ack path
    [DESIGN]; false keeps only the episodes, for the highest insert rates."""
    eviction: str = "fifo"
    """Which episode a full buffer overwrites: `fifo` the oldest [DESIGN]; `random` a slot
    drawn uniformly, as the reference does [HER-py] (reproducible: a hash of the run's seed
    and the episode id, so a restarted replay rebuilds the same buffer from its log)."""

    def __post_init__(self) -> None:
        _check(self.buffer_transitions >= 1, "replay.buffer_transitions",
               self.buffer_transitions, "be >= 1")
        _check(self.min_episodes_to_sample >= 1, "replay.min_episodes_to_sample",
               self.min_episodes_to_sample, "be >= 1")
        _check(self.rate_tolerance_updates >= 0, "replay.rate_tolerance_updates",
               self.rate_tolerance_updates, "be >= 0")
        _check(self.max_message_bytes >= 1024, "replay.max_message_bytes",
               self.max_message_bytes, "be >= 1024")
        _positive("replay.sample_timeout_s", self.sample_timeout_s)
        _check(self.insert_workers >= 1, "replay.insert_workers", self.insert_workers,
               "be >= 1")
        _check(self.eviction in EVICTIONS, "replay.eviction", self.eviction,
               "be fifo or random")


@dataclass
class ActorConfig:
    num_actors: int = 1
    """Rollout workers started by `hercs up` (the paper used one)."""
    insert_timeout_s: float = 10.0
    """An insert without an InsertAck after this long is retried with the same (actor, seq)."""
    envs_per_process: int = 1
    """Envs one actor process steps side by side, with one batched policy call per step for
    all of them [DESIGN]; more envs per process amortise the per-step inference and the
    process's fixed costs (docs/PERFORMANCE.md)."""
    insert_queue: int = 0
    """Finished episodes per env that may wait behind the one whose insert is in flight
    before the rollout loop blocks (0: none, the next episode starts only once the last is
    acked). Each waiting episode was acted with weights that age while it waits; 0 cost no
    epoch time against the old default of 2 (docs/PERFORMANCE.md §2) [DESIGN]."""

    def __post_init__(self) -> None:
        _check(self.insert_queue >= 0, "actor.insert_queue", self.insert_queue, "be >= 0")
        _check(self.num_actors >= 0, "actor.num_actors", self.num_actors, "be >= 0")
        _check(1 <= self.envs_per_process <= 256, "actor.envs_per_process",
               self.envs_per_process, "be between 1 and 256")
        _positive("actor.insert_timeout_s", self.insert_timeout_s)


LEARNER_DEVICES = ("auto", "cpu", "cuda")
PRECISIONS = ("fp32", "bf16")


@dataclass
class LearnerConfig:
    device: str = "auto"
    """Where the DDPG update runs: auto (a CUDA GPU when torch sees one, else the CPU), cpu,
    cuda or cuda:N. The paper's runs used the CPU; results do not depend on it beyond float
    rounding."""
    precision: str = "fp32"
    """fp32, or bf16: the online networks' passes (Q(s, u), μ(s), Q(s, μ(s))) under bf16
    autocast, with fp32 master weights, Adam, TD target y (the target networks run in fp32),
    losses and normaliser [DESIGN]. Pays only where bf16 matrix products are native (recent
    GPUs; CPUs with AVX-512 BF16 or AMX): docs/PERFORMANCE.md §4."""

    prefetch_depth: int = 0
    """Batches sampled ahead of the one the update loop is training on, to hide sampling and
    transport. In the asynchronous schedule each one lets the rate limiter admit one cycle of
    episodes more before their weights exist: one cycle of policy lag per batch of depth.
    0 (ask when the loop wants a batch) cost no epoch time against the old default of 3 on
    one box (docs/PERFORMANCE.md §2); a learner far from its replay may want 1. Lockstep asks
    for nothing ahead whatever this says [DESIGN]."""

    def __post_init__(self) -> None:
        _check(self.prefetch_depth >= 0, "learner.prefetch_depth", self.prefetch_depth,
               "be >= 0 (0: ask for a batch only when the update loop wants it)")
        _check(self.precision in PRECISIONS, "learner.precision", self.precision,
               "be fp32 or bf16")
        base, _, index = self.device.partition(":")
        _check(base in LEARNER_DEVICES and (not index or (base == "cuda" and index.isdigit())),
               "learner.device", self.device, "be auto, cpu, cuda or cuda:N")


@dataclass
class LaunchConfig:
    max_restarts: int = 5
    """How often `hercs up` starts a child that died again before it gives the run up (the live
    view is never restarted); a child that ran 5 minutes has its count reset [DESIGN]."""
    restart_backoff_s: float = 1.0
    """Delay before the first restart of a child; it doubles with each restart, up to 30 s."""

    def __post_init__(self) -> None:
        _check(self.max_restarts >= 0, "launch.max_restarts", self.max_restarts, "be >= 0")
        _positive("launch.restart_backoff_s", self.restart_backoff_s)


@dataclass
class TransportConfig:
    listen: list[str] = field(default_factory=lambda: ["tcp/127.0.0.1:0"])
    """Endpoints the router listens on (`hercs up`, `hercs router`); port 0: any free port,
    picked at start (so runs on one host never collide) and recorded in the run directory's
    router.json, where `hercs actor`/`hercs live --run-dir` find it."""
    connect: list[str] = field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    """Endpoints clients connect to; they retry until the router is up."""
    wait_s: float = 0.0
    """How long a client waits for its router, and an actor or live view for its run's
    replay, before it exits with status 3 saying what it waited for and which runs the router
    knows. 0 waits for ever (a log line every 10 s says what for): actors may be started
    before the run."""

    def __post_init__(self) -> None:
        for name in ("listen", "connect"):
            for endpoint in getattr(self, name):
                problem = endpoint_problem(endpoint)
                _check(problem is None, f"transport.{name}", endpoint, problem or "")
        _check(math.isfinite(self.wait_s) and self.wait_s >= 0, "transport.wait_s",
               self.wait_s, "be a finite number >= 0 (0: wait for ever)")


@dataclass
class SecurityConfig:
    """Authentication and access control of the Zenoh network (hercs.security,
    docs/SECURITY.md). Paths are resolved against the working directory at start-up."""

    tls_ca: str = ""
    """The CA certificate (PEM) that signed the router's and every client's certificate."""
    tls_cert: str = ""
    """This process's certificate (PEM): the router's (its SAN lists the addresses clients
    use) or a client's (common name = its role: actor, replay, learner, ...). `{role}` in the
    path is replaced by the process's role (`router` for the router)."""
    tls_key: str = ""
    """The private key of `tls_cert` (`{role}` replaced likewise)."""
    credentials: str = ""
    """A file of `user:password` lines: the router's dictionary, or a client's own line (the
    user is its role)."""
    access_control: bool = True
    """With TLS or credentials, the router allows each role only its own keys."""
    allow_insecure: bool = False
    """Let a router listen on a non-loopback address without TLS (a network you trust)."""


VIEWER_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")


@dataclass
class ViewConfig:
    live: bool = False
    """`hercs up` also starts the live view (`hercs live`): metrics, episodes and clusters
    streamed to Rerun while training runs, with the entity paths of `hercs view` [DESIGN]."""
    episode_every: int = 20
    """The live view draws the 3D trajectory of every episode whose id is a multiple of this
    (fetched from the replay); 0 = none. Scalars and failed goals cover every episode."""
    viewer: str = "spawn"
    """Where the live view streams: 'spawn' (a local Rerun viewer started by rerun-sdk on port
    9876, or the one already listening there), 'none', or a viewer's gRPC URL such as
    'rerun+http://HOST:9876/proxy'."""
    save: str = ""
    """Also write the live recording to this .rrd file ('' = no file), e.g. on a machine
    without a display."""

    def __post_init__(self) -> None:
        _check(self.episode_every >= 0, "view.episode_every", self.episode_every, "be >= 0")
        _check(self.viewer in ("spawn", "none")
               or (self.viewer.startswith(VIEWER_SCHEMES) and self.viewer.endswith("/proxy")),
               "view.viewer", self.viewer,
               "be 'spawn', 'none' or a Rerun gRPC URL like rerun+http://HOST:9876/proxy")
        _check(self.save == "" or self.save.endswith(".rrd"), "view.save", self.save,
               "be '' or a path ending in .rrd")


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

    def __post_init__(self) -> None:
        spec = self.task.spec
        _check(self.replay.buffer_transitions >= spec.episode_steps, "replay.buffer_transitions",
               self.replay.buffer_transitions, f"hold at least one episode ({spec.episode_steps})")
        _check(not (self.training.schedule == "lockstep" and self.replay.free_run),
               "replay.free_run", self.replay.free_run,
               "be false with training.schedule lockstep (lockstep admits by cycle)")
        # The replay's rate limiter needs a window wider than one request plus one insert, or
        # inserts and samples could both wait forever; checked here too so that `hercs up`
        # refuses the run before it starts any service.
        least = (self.training.minibatches_per_cycle + self.training.updates_per_episode) / 2
        _check(self.training.schedule == "lockstep" or self.replay.free_run
               or self.replay.rate_tolerance_updates >= least,
               "replay.rate_tolerance_updates", self.replay.rate_tolerance_updates,
               f"be at least (training.minibatches_per_cycle + updates per episode)/2 = "
               f"{least:g}, or inserts and samples could both wait forever")

    @property
    def capacity_episodes(self) -> int:
        return self.replay.buffer_transitions // self.task.spec.episode_steps

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> HercsConfig:
        return _build(cls, data, "")


RETIRED_KEYS: dict[str, str] = {
    "cluster.failure_threshold": "an episode fails when it does not succeed by the task's own "
                                 "rule (TaskSpec.is_success)",
}
"""Keys that configs saved by earlier versions hold and this version ignores (with a log line),
so that old runs stay readable; any other unknown key is refused."""


def _build(cls: type, data: Any, where: str) -> Any:
    """Build dataclass `cls` from a mapping, refusing unknown keys and wrong types."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where or 'config'}: got {data!r}, must be a mapping")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for key in [k for k in data if f"{where}.{k}" in RETIRED_KEYS]:
        log.info("config: ignoring %s.%s (%s)", where, key, RETIRED_KEYS[f"{where}.{key}"])
        data = {k: v for k, v in data.items() if k != key}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"{where or 'config'}: unknown key(s) {unknown}; known: {sorted(names)}"
        )
    kwargs = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else key
        kwargs[key] = _coerce(hints[key], value, path)
    return cls(**kwargs)


def _coerce(hint: Any, value: Any, where: str) -> Any:
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return _build(hint, value, where)
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: got {value!r}, must be true or false"
                          + (" (yes, no, on and off are not taken as booleans)"
                             if str(value).lower() in YAML11_BOOLS else ""))
    if hint is int:
        if isinstance(value, bool):
            raise ConfigError(f"{where}: got {value!r}, must be an integer")
        if isinstance(value, str):
            value = _parse_number(value, where)
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, int):
            return value
        raise ConfigError(f"{where}: got {value!r}, must be an integer")
    if hint is float:
        if isinstance(value, bool):
            raise ConfigError(f"{where}: got {value!r}, must be a number")
        if isinstance(value, str):
            value = _parse_number(value, where)
        if isinstance(value, int | float):
            return float(value)
        raise ConfigError(f"{where}: got {value!r}, must be a number")
    if hint is str:
        if isinstance(value, str):
            return value
        raise ConfigError(f"{where}: got {value!r}, must be a string")
    if typing.get_origin(hint) is list:
        if isinstance(value, str):
            value = [v for v in value.split(",") if v]
        if not isinstance(value, list):
            raise ConfigError(f"{where}: got {value!r}, must be a list")
        (item,) = typing.get_args(hint)
        return [_coerce(item, v, f"{where}[{i}]") for i, v in enumerate(value)]
    raise ConfigError(f"{where}: unsupported config type {hint!r}")  # pragma: no cover


YAML11_BOOLS = frozenset({"yes", "no", "on", "off"})
"""Words PyYAML's YAML 1.1 resolver reads as booleans; `StrictBoolLoader` keeps them strings."""


class StrictBoolLoader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2's booleans: only true and false (any case) are
    booleans; yes, no, on and off stay strings, which a boolean field then refuses."""


StrictBoolLoader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
StrictBoolLoader.add_implicit_resolver(
    "tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
    list("tTfF"))


def _did_you_mean(name: str, known: typing.Iterable[str], prefix: str = "") -> str:
    """' did you mean 'x.y'?' for the closest known name, or '' if none is close."""
    close = difflib.get_close_matches(name, list(known), n=1)
    return f" did you mean {prefix + close[0]!r}?" if close else ""


def _parse_number(text: str, where: str) -> int | float:
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"{where}: got {text!r}, must be a number") from None


def apply_overrides(config: HercsConfig, overrides: list[str]) -> HercsConfig:
    """Return a new config with `section.field=value` overrides applied and validated.

    Values are parsed as YAML scalars (so `true`, `1e-3`, `[a, b]` work).
    """
    data = config.to_dict()
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or "." not in key:
            raise ConfigError(
                f"override {item!r}: must look like section.field=value, e.g. ddpg.lr_actor=1e-3"
            )
        section, _, name = key.strip().partition(".")
        if section not in data or not isinstance(data[section], dict):
            raise ConfigError(f"override {item!r}: unknown section {section!r};"
                              f"{_did_you_mean(section, data)} known: {sorted(data)}")
        if name not in data[section]:
            raise ConfigError(f"override {item!r}: unknown field {key.strip()!r};"
                              f"{_did_you_mean(name, data[section], section + '.')} known in "
                              f"{section}: {sorted(data[section])} (`hercs config` prints "
                              "every field with its value)")
        if isinstance(data[section][name], str):
            # A string field takes the text as it is, so a run named "007" stays a string.
            data[section][name] = raw
            continue
        try:
            value = yaml.load(raw, Loader=StrictBoolLoader) if raw.strip() else ""
        except yaml.YAMLError as exc:
            raise ConfigError(f"override {item!r}: value is not valid YAML ({exc})") from None
        data[section][name] = value
    return HercsConfig.from_dict(data)


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
    Path(path).write_text(yaml.safe_dump(config.to_dict(), sort_keys=False))
