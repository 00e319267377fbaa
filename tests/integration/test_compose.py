"""docker-compose.yml and the Dockerfile, checked statically (no Docker engine runs here):
every service's command is a valid `hercs` command line resolving to the right config, the
services find the router by its service name, actors can be scaled, and what `docker compose
config` would refuse (undeclared volumes, unknown depends_on, a missing build context) is
absent. Compose's `${VAR:-default}` interpolation is applied as compose does.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from apps.cli import SERVICES, build_parser, resolve_config
from hercs.config import HercsConfig
from hercs.security import listen_problem

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
ROUTER = "tls/router:7447"
SECRETS = "/run/secrets"
ROLES = {"router", "replay", "clusterer", "learner", "evaluator", "actor"}

_VAR = re.compile(r"\$\$|\$\{(\w+)(?::?-([^}]*))?\}|\$(\w+)")


def interpolate(value: Any, env: Mapping[str, str]) -> Any:
    """Compose's variable substitution: ${VAR}, ${VAR:-default}, ${VAR-default}, $VAR, $$."""
    if isinstance(value, dict):
        return {k: interpolate(v, env) for k, v in value.items()}
    if isinstance(value, list):
        return [interpolate(v, env) for v in value]
    if not isinstance(value, str):
        return value

    def sub(m: re.Match[str]) -> str:
        if m.group(0) == "$$":
            return "$"
        name = m.group(1) or m.group(3)
        if name in env and (env[name] or ":-" not in m.group(0)):
            return env[name]
        if m.group(2) is None:
            raise AssertionError(f"{m.group(0)} has no default and is not set")
        return m.group(2)

    return _VAR.sub(sub, value)


def load_compose(env: Mapping[str, str]) -> dict[str, Any]:
    return interpolate(yaml.safe_load((REPO / "docker-compose.yml").read_text()), env)


def parse_command(name: str, command: list[str]) -> tuple[Any, HercsConfig]:
    parser, _ = build_parser()
    try:
        args = parser.parse_args(command)
    except SystemExit:
        raise AssertionError(f"service {name}: `hercs {' '.join(command)}` does not "
                             "parse") from None
    return args, resolve_config(args)


ENVS = {
    "defaults": ({}, {"run": "compose", "task": "push", "method": "her-cs", "seed": 1,
                      "epochs": 200}),
    "overridden": ({"HERCS_RUN": "pick-2", "HERCS_TASK": "pick", "HERCS_METHOD": "her-ebp-cs",
                    "HERCS_SEED": "2", "HERCS_EPOCHS": "50"},
                   {"run": "pick-2", "task": "pick", "method": "her-ebp-cs", "seed": 2,
                    "epochs": 50}),
}


@pytest.mark.parametrize(("env", "expected"), ENVS.values(), ids=ENVS.keys())
def test_every_service_runs_a_valid_hercs_command(env: dict[str, str],
                                                  expected: dict[str, Any]) -> None:
    services = load_compose(env)["services"]
    assert set(services) == ROLES

    args, config = parse_command("router", services["router"]["command"])
    assert args.command == "router"
    assert config.transport.listen == ["tls/0.0.0.0:7447"]
    assert "7447:7447" in services["router"].get("ports", [])
    # the published port is secured: mutual TLS with the certificates mounted as secrets
    assert listen_problem(config.security, config.transport.listen) is None
    declared = load_compose(env)["secrets"]
    for name in sorted(ROLES):
        _, config = parse_command(name, services[name]["command"])
        sec = config.security
        assert (sec.tls_ca, sec.tls_cert, sec.tls_key) == (
            f"{SECRETS}/ca.pem", f"{SECRETS}/{{role}}.pem", f"{SECRETS}/{{role}}.key"), name
        mounted = {item["target"]: item["source"] for item in services[name]["secrets"]}
        assert mounted == {"ca.pem": "ca", f"{name}.pem": f"{name}_cert",
                           f"{name}.key": f"{name}_key"}, f"{name} gets only its own key"
        for source in mounted.values():
            assert declared[source]["file"].startswith(env.get("HERCS_CERTS", "./certs"))

    for name in sorted(ROLES - {"router"}):
        service = services[name]
        args, config = parse_command(name, service["command"])
        assert args.command == name and name in SERVICES
        assert config.transport.connect == [ROUTER], f"{name} must reach the router by name"
        assert config.run.name == expected["run"], name
        assert "runs:/runs" in service["volumes"], name
        if name == "actor":  # the rest comes from the replay's served config
            continue
        assert args.ident == f"{name}-0"
        assert config.run.run_dir == "/runs"
        got = (config.task.name, config.run.method, config.run.seed, config.training.epochs)
        assert got == (expected["task"], expected["method"], expected["seed"],
                       expected["epochs"]), name


def test_actor_scales() -> None:
    actor = load_compose({})["services"]["actor"]
    args, _ = parse_command("actor", actor["command"])
    assert args.ident is None, "a fixed --id would collide between scaled actors"
    for fixed in ("container_name", "hostname", "ports"):
        assert fixed not in actor, f"actor has {fixed}: `--scale actor=8` would collide"


def test_compose_structure_is_valid() -> None:
    doc = load_compose({})
    services = doc["services"]
    declared_volumes = set(doc.get("volumes") or {})
    for name, service in services.items():
        assert "build" in service or "image" in service, name
        if "build" in service:
            context = service["build"] if isinstance(service["build"], str) else \
                service["build"].get("context", ".")
            assert (REPO / context / "Dockerfile").is_file(), name
        depends = service.get("depends_on") or []
        names = list(depends) if isinstance(depends, list | dict) else [depends]
        unknown = set(names) - set(services)
        assert not unknown, f"{name} depends on unknown services {unknown}"
        assert name not in names
        for volume in service.get("volumes", []):
            source = volume.split(":")[0]
            if not source.startswith(("/", ".", "~")):
                assert source in declared_volumes, f"{name}: volume {source!r} not declared"
        assert isinstance(service["command"], list), f"{name}: command must be a list"
    # shutdown mirrors `hercs up`: everything depends on the router, the services on the replay
    for name in ROLES - {"router"}:
        assert "router" in services[name]["depends_on"], name
    for name in ROLES - {"router", "replay"}:
        assert "replay" in services[name]["depends_on"], name


def test_dockerfile_installs_cpu_torch_then_every_package() -> None:
    dockerfile = (REPO / "Dockerfile").read_text()
    lines = [line.strip() for line in dockerfile.splitlines()
             if line.strip() and not line.lstrip().startswith("#")]
    assert lines[0] == "FROM python:3.11-slim"
    torch = next(i for i, line in enumerate(lines) if "torch==2.13.0" in line)
    assert "--index-url https://download.pytorch.org/whl/cpu" in lines[torch]
    project = next(i for i, line in enumerate(lines) if re.search(r"pip install \.$", line))
    assert torch < project
    assert 'ENTRYPOINT ["hercs"]' in lines
    copied = {part for line in lines if line.startswith("COPY ")
              for part in line.split()[1:-1]}
    packages = tomllib.loads((REPO / "pyproject.toml").read_text())[
        "tool"]["setuptools"]["packages"]["find"]["include"]
    for package in packages:
        assert package.rstrip("*") in copied, f"{package} is not copied into the image"
    for path in copied:
        assert (REPO / path).exists(), path
    ignored = {line.strip() for line in (REPO / ".dockerignore").read_text().splitlines()
               if line.strip() and not line.startswith("#")}
    assert {".venv", "runs", ".git"} <= ignored
    assert not copied & ignored
