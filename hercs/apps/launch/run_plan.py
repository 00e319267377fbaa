"""What `hercs up` runs (hercs/apps/launch/launcher.py): the run's name, where its children
connect, and its children in start order, each with the command that starts it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from hercs.apps.launch.child_process import service_argv
from hercs.config import HercsConfig
from hercs.roles import SERVICE_ROLES


@dataclass(frozen=True)
class ChildSpec:
    """One service process of the run."""

    role: str
    ident: str

    @property
    def log_name(self) -> str:
        return f"{self.ident}.log"

    def __str__(self) -> str:
        return f"{self.role} {self.ident}"


CommandFactory = Callable[[ChildSpec, Path], list[str]]
"""Builds a child's argv from its spec and the run's config.yaml (injectable for tests)."""


def child_argv(spec: ChildSpec, config_path: Path) -> list[str]:
    """The real child: `python -m hercs.apps.cli <role> --config <config.yaml> --id <ident>`."""
    return service_argv(spec.role, spec.ident, config_path)


def plan_children(config: HercsConfig) -> list[ChildSpec]:
    """Every child of a run, in start order (the live view only with `view.live`, the
    learner not with `launch.learner_elsewhere`)."""
    roles = [r.name for r in SERVICE_ROLES.values()  # in start order
             if not r.actor_node and (not r.optional or config.view.live)
             and not (r.name == "learner" and config.launch.learner_elsewhere)]
    specs = [ChildSpec(role, f"{role}-0") for role in roles]
    specs += [ChildSpec("actor", f"actor-{i}") for i in range(config.actor.num_actors)]
    return specs


def default_run_name(config: HercsConfig, now: datetime | None = None) -> str:
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    return f"{config.task.name}-{config.run.method}-s{config.run.seed}-{stamp}"


def loopback_endpoints(listen: list[str]) -> list[str]:
    """Where a process on this host reaches a router listening on `listen`: a wildcard host
    (0.0.0.0, [::]) becomes loopback; a concrete address stays."""
    out = []
    for endpoint in listen:
        proto, sep, rest = endpoint.partition("/")
        if sep and rest.startswith("0.0.0.0:"):
            rest = "127.0.0.1:" + rest.removeprefix("0.0.0.0:")
        elif sep and rest.startswith("[::]:"):
            rest = "[::1]:" + rest.removeprefix("[::]:")
        out.append(f"{proto}{sep}{rest}")
    return out


def resolve_run(config: HercsConfig, now: datetime | None = None,
                listening: list[str] | None = None) -> HercsConfig:
    """The config the children get: a run name, and `connect` = the embedded router, which
    listens on `listening` (default: `transport.listen`; the concrete ports once a port 0
    has been given one). `listen` stays as asked, so that a resumed run picks a port anew."""
    data = config.resolved().to_dict()
    data["run"]["name"] = config.run.name or default_run_name(config, now)
    data["transport"]["connect"] = loopback_endpoints(listening or config.transport.listen)
    return HercsConfig.from_dict(data)


LOOPBACK_HOSTS = ("127.0.0.1", "[::1]", "localhost")


def remote_actor_command(config: HercsConfig) -> tuple[str, bool]:
    """The `hercs actor` command that joins the run `config` describes (its children's config:
    `transport.connect` holds the router's concrete ports), and whether another host can use
    it: False where the router listens on loopback only. A wildcard listen address reads HOST,
    the name other hosts know this one by."""
    endpoints = []
    reachable = False
    for asked, concrete in zip(config.transport.listen, config.transport.connect, strict=False):
        proto, _, rest = concrete.partition("/")
        host, _, port = rest.rpartition(":")
        wildcard = asked.partition("/")[2].rpartition(":")[0] in ("0.0.0.0", "[::]")
        reachable = reachable or wildcard or host not in LOOPBACK_HOSTS
        endpoints.append(f"{proto}/{'HOST' if wildcard else host}:{port}")
    words = ["hercs actor"]
    for endpoint in endpoints or ["ENDPOINT"]:
        words += ["--connect", endpoint]
    words += ["--run", config.run.name]
    security = config.security
    for flag, path in (("--tls-ca", security.tls_ca), ("--tls-cert", security.tls_cert),
                       ("--tls-key", security.tls_key), ("--credentials", security.credentials)):
        if path:
            words += [flag, Path(path.replace("{role}", "actor")).name]
    return " ".join(words), reachable
