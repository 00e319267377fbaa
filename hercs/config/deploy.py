"""The deployment's sections of the config tree (hercs.config): how the actor and learner
processes run, how `hercs up` launches them, how they connect and authenticate, and the live
view; with the checks of Zenoh endpoints. The sources are named as in hercs.config."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from hercs.config.checks import _check, _positive
from hercs.config.limits import MAX_ENVS_PER_PROCESS
from hercs.config.unsaved import UNSAVED
from hercs.errors import ConfigError

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
    insert_queue: int = field(default=0, metadata={UNSAVED: 2})
    """Finished episodes per env that may wait behind the one whose insert is in flight
    before the rollout loop blocks (0: none, the next episode starts only once the last is
    acked). Each waiting episode was acted with weights that age while it waits; 0 cost no
    epoch time against the old default of 2 (docs/PERFORMANCE.md §2), which a run whose saved
    config has no such field ran with [DESIGN]."""

    def __post_init__(self) -> None:
        _check(self.insert_queue >= 0, "actor.insert_queue", self.insert_queue, "be >= 0")
        _check(self.num_actors >= 0, "actor.num_actors", self.num_actors, "be >= 0")
        _check(1 <= self.envs_per_process <= MAX_ENVS_PER_PROCESS, "actor.envs_per_process",
               self.envs_per_process, f"be between 1 and {MAX_ENVS_PER_PROCESS}")
        _positive("actor.insert_timeout_s", self.insert_timeout_s)


LEARNER_DEVICES = ("auto", "cpu", "cuda")
PRECISIONS = ("fp32", "bf16", "tf32")


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
    GPUs; CPUs with AVX-512 BF16 or AMX): docs/PERFORMANCE.md §4. tf32: every matrix product
    rounds its operands to TF32's 10 mantissa bits and sums in fp32, on any device: the
    arithmetic of the authors' runs had their GPU been Ampere or newer (torch 1.10.1 turned
    TF32 on there by default; their GPU model is not published);
    slower than fp32, for the comparison only."""

    parallel_halves: bool = True
    """Run each update's two halves at once on two threads (the critic's TD target, loss and
    backward pass beside the actor's loss, backward pass and Adam step), on a CPU learner.
    Bit-identical to one thread (tests/unit/learner/test_learner_halves.py); the second thread
    takes a core the actor leaves idle (docs/PERFORMANCE.md §3). Ignored on a GPU."""

    cuda_graph: bool = True
    """On a GPU, capture the whole update (target, losses, backward passes, fused Adam steps,
    the loss sums) once as a CUDA graph and replay it per minibatch, the losses read back
    only for the epoch's metrics row (hercs/learner/cuda_graph.py). The same arithmetic as the
    eager GPU update to float tolerance. Where the capture fails, the learner says why and
    trains with the eager update. Ignored on a CPU."""

    prefetch_depth: int = field(default=0, metadata={UNSAVED: 3})
    """Batches sampled ahead of the one the update loop is training on, to hide sampling and
    transport. In the asynchronous schedule each one lets the rate limiter admit one cycle of
    episodes more before their weights exist: one cycle of policy lag per batch of depth.
    0 (ask when the loop wants a batch) cost no epoch time against the old default of 3 on
    one box (docs/PERFORMANCE.md §2), which a run whose saved config has no such field ran
    with; a learner far from its replay may want 1. Lockstep asks for nothing ahead whatever
    this says [DESIGN]."""

    def __post_init__(self) -> None:
        _check(self.prefetch_depth >= 0, "learner.prefetch_depth", self.prefetch_depth,
               "be >= 0 (0: ask for a batch only when the update loop wants it)")
        _check(self.precision in PRECISIONS, "learner.precision", self.precision,
               f"be one of {', '.join(PRECISIONS)}")
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
    stall_factor: float = 10.0
    """A run in which no epoch ends for this many times its slowest epoch so far has stalled:
    `hercs up` says what stopped moving and where to look, stops every service and exits 5.
    Before its first epoch ends the bound is this many times the first epoch the config
    predicts on a slow machine (hercs/apps/launch/stall.py). 10 lets an epoch be slowed by a
    service's restart or a network cut of a minute without a false alarm: the chaos soaks'
    slowest epochs, with a kill or a cut in them, took 1.5x their median [DESIGN]. 0: never
    (a learner held in a debugger)."""
    learner_elsewhere: bool = False
    """`hercs up` starts no learner: the run's learner is a process of its own that joins the
    run over the router, as a stacked learner serving several runs does (`hercs
    learner-stack`, `hercs sweep --stacked`). The run ends when that learner says it finished (its
    `RunProgress`), and with status 4 when it says the run's training diverged."""

    def __post_init__(self) -> None:
        _check(isinstance(self.learner_elsewhere, bool), "launch.learner_elsewhere",
               self.learner_elsewhere, "be true or false")
        _check(self.max_restarts >= 0, "launch.max_restarts", self.max_restarts, "be >= 0")
        _positive("launch.restart_backoff_s", self.restart_backoff_s)
        _check(self.stall_factor == 0 or self.stall_factor >= 2, "launch.stall_factor",
               self.stall_factor, "be 0 (never) or >= 2 (below, an epoch a little slower "
               "than the slowest so far would end the run)")


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
    rediscover_s: float = 20.0
    """A service whose requests on a key that answered before find no queryable for this
    long, while its session has a router, reopens its session and declares everything again
    (a session that reconnected after a cut but never relearned the router's declarations:
    hercs.net.rediscovery); repeated reopens of one outage wait twice as long each time, up to
    160 s. 0: never."""
    cut_off_s: float = 15.0
    """A service whose requests have found no router for this long (a cut longer than Zenoh's
    10 s lease ended its session) opens a new session, with a new Zenoh id, and declares
    everything again: the router takes it as soon as the link is back. Zenoh's own reconnect
    keeps the old id, which the router can hold for up to a minute after a long two-way cut
    (docs/results/net_faults.md); shorter cuts are left to it. 0: never."""

    def __post_init__(self) -> None:
        _check(math.isfinite(self.rediscover_s) and self.rediscover_s >= 0,
               "transport.rediscover_s", self.rediscover_s, "be a finite number >= 0 (0: never)")
        _check(self.cut_off_s == 0 or (math.isfinite(self.cut_off_s) and self.cut_off_s >= 10),
               "transport.cut_off_s", self.cut_off_s, "be 0 (never) or a finite number >= 10 "
               "(a session without a router is one Zenoh is already reconnecting, an attempt "
               "every 10 s; a shorter bound would replace that after every cut)")
        for name in ("listen", "connect"):
            for endpoint in getattr(self, name):
                problem = endpoint_problem(endpoint)
                _check(problem is None, f"transport.{name}", endpoint, problem or "")
        _check(math.isfinite(self.wait_s) and self.wait_s >= 0, "transport.wait_s",
               self.wait_s, "be a finite number >= 0 (0: wait for ever)")


@dataclass
class SecurityConfig:
    """Authentication and access control of the Zenoh network (hercs.net.security,
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
