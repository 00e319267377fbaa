"""docker-compose.yml and the Dockerfile, checked statically (no Docker engine runs here): valid
`hercs` commands and configs, the router found by its service name, actors scalable, nothing
`docker compose config` would refuse, compose's interpolation and the entrypoint
(deploy/compose-entrypoint.sh) applied as compose does. `make compose-test` runs it for real.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from hercs.apps.cli.main import build_parser, resolve_config
from hercs.config import HercsConfig
from hercs.net.security import listen_problem
from hercs.roles import SERVICE_ROLES

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
ROUTER = "tls/router:7447"
SECRETS = "/run/secrets"
ROLES = {"router"} | {r.name for r in SERVICE_ROLES.values() if r.compose}
"""The compose services: the router and every role deployed there (hercs/roles.py)."""

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


ENTRYPOINT = ["sh", "/usr/local/bin/hercs-compose"]


def effective_command(service: dict[str, Any]) -> list[str]:
    """The `hercs` arguments a service runs: its command, plus what the compose entrypoint
    (deploy/compose-entrypoint.sh) appends: one `--set` per word of HERCS_SET."""
    command = list(service["command"])
    if service.get("entrypoint") is None:
        return command
    assert service["entrypoint"] == ENTRYPOINT
    for word in (service.get("environment") or {}).get("HERCS_SET", "").split():
        command += ["--set", word]
    return command


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
    # what `make compose-test` runs: tiny training settings through HERCS_SET
    "compose-test": ({"HERCS_RUN": "ci-1", "HERCS_TASK": "reach", "HERCS_EPOCHS": "2",
                      "HERCS_SET": "training.cycles_per_epoch=10  training.eval_episodes=5",
                      "HERCS_CERTS": "/var/cache/hercs-ci/last-run/certs"},
                     {"run": "ci-1", "task": "reach", "method": "her-cs", "seed": 1, "epochs": 2,
                      "cycles_per_epoch": 10, "eval_episodes": 5}),
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
        _, config = parse_command(name, effective_command(services[name]))
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
        assert service["entrypoint"] == ENTRYPOINT, name
        assert service["environment"]["HERCS_SET"] == env.get("HERCS_SET", ""), name
        args, config = parse_command(name, effective_command(service))
        assert args.command == name and name in SERVICE_ROLES
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
        defaults = HercsConfig().training
        assert config.training.cycles_per_epoch == expected.get(
            "cycles_per_epoch", defaults.cycles_per_epoch), name
        assert config.training.eval_episodes == expected.get(
            "eval_episodes", defaults.eval_episodes), name


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


def dockerfile_stages() -> dict[str, list[str]]:
    """The Dockerfile's instructions (comments dropped, continuations joined) per stage name;
    "" holds what comes before the first FROM."""
    text = re.sub(r"\\\n", " ", (REPO / "Dockerfile").read_text())
    stages: dict[str, list[str]] = {"": []}
    current = ""
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        m = re.match(r"FROM\s+\S+\s+AS\s+(\S+)$", line, re.IGNORECASE)
        if m:
            current = m.group(1)
            stages[current] = []
        stages[current].append(line)
    return stages


# What the `services` image leaves out (the Dockerfile's list), by import name.
VIEW_ONLY = {"rerun-sdk": "rerun", "matplotlib": "matplotlib", "imageio-ffmpeg": "imageio_ffmpeg"}


def test_dockerfile_installs_cpu_torch_then_every_package() -> None:
    stages = dockerfile_stages()
    # the base and the wheel source are build arguments; the defaults need only a registry
    assert "ARG BASE_IMAGE=python:3.11-slim" in stages[""]
    assert stages["base"][0] == "FROM ${BASE_IMAGE} AS base"
    deps, build = stages["deps"], stages["build"]
    assert "ARG TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu" in deps
    for stage in ("deps", "build", "deps-full"):  # every stage that runs pip
        for arg in ("PIP_NO_INDEX", "PIP_FIND_LINKS", "PIP_INDEX_URL"):
            assert f"ARG {arg}" in stages[stage], f"{stage}: offline builds set {arg}"
    torch = next(i for i, line in enumerate(deps) if "torch==2.13.0" in line)
    assert "--index-url ${TORCH_INDEX_URL}" in deps[torch]
    requirements = next(i for i, line in enumerate(deps) if "pip install -r services.txt" in line)
    assert torch < requirements
    assert any(re.search(r"pip install --no-deps --target /opt/hercs \.$", line) for line in build)
    assert any("pip install -r all.txt" in line for line in stages["deps-full"])
    # the wheelhouse goes into the deps stage only, never into an image that is shipped
    assert "COPY deploy/wheelhouse /wheels" in deps
    for target, venv in (("services", "deps"), ("full", "deps-full")):
        lines = stages[target]
        assert lines[0] == f"FROM base AS {target}"
        assert f"COPY --from={venv} /opt/venv /opt/venv" in lines
        assert "COPY --from=build /opt/hercs /opt/hercs" in lines
        assert not any("wheelhouse" in line or "/wheels" in line for line in lines), target
        assert 'ENTRYPOINT ["hercs"]' in lines, target
        assert "COPY deploy/compose-entrypoint.sh /usr/local/bin/hercs-compose" in lines
    assert list(stages)[-1] == "full", "a plain `docker build .` gives every dependency"

    # the services image: pyproject's dependencies less the view/plot/video ones
    deps_listed = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    names = {re.split(r"[<>=!~;\[ ]", d)[0].lower() for d in deps_listed}
    left_out = re.search(r"not in \(([^)]*)\)", " ".join(deps))
    assert left_out, "the services' requirement filter is gone"
    excluded = set(re.findall(r"'([^']+)'", left_out.group(1)))
    assert excluded == set(VIEW_ONLY) and excluded <= names

    copied = {part for line in deps + build if line.startswith("COPY ")
              for part in line.split()[1:-1]}
    packages = tomllib.loads((REPO / "pyproject.toml").read_text())[
        "tool"]["setuptools"]["packages"]["find"]["include"]
    for package in packages:
        assert package.rstrip("*") in copied, f"{package} is not copied into the image"
    for path in copied:
        assert (REPO / path).exists(), path
    ignored = {line.strip() for line in (REPO / ".dockerignore").read_text().splitlines()
               if line.strip() and not line.startswith("#")}
    assert {".venv", "runs", ".git", "certs"} <= ignored
    assert not copied & ignored
    assert {"!deploy/wheelhouse", "!deploy/compose-entrypoint.sh"} <= ignored

    # compose builds the services target
    doc = load_compose({})
    for name, service in doc["services"].items():
        assert service["build"] == {"context": ".", "target": "services"}, name
        assert service["image"] == "hercs:latest", name


def test_services_import_no_view_dependency() -> None:
    """The services image lacks rerun-sdk, matplotlib and imageio-ffmpeg: no module a service
    command imports may import them at module level (only `hercs view|plot|live|eval` do)."""
    modules = ["hercs.apps.cli", "hercs.apps.launch.router", "hercs.apps.deploy.certs",
               *(r.module for r in SERVICE_ROLES.values() if r.compose)]
    heavy = [*VIEW_ONLY.values(), "pyarrow"]
    # pandas is a dev-only package here (rliable's, for studies/claims/claims.py), absent from the
    # image; where installed, scikit-learn imports it and it imports pyarrow: block it so the
    # check sees what the image sees
    code = ("import importlib, sys\n"
            "sys.modules['pandas'] = None\n"
            f"for m in {modules!r}: importlib.import_module(m)\n"
            f"print(sorted(set({heavy!r}) & set(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert out.strip() == "[]", f"a service path imports {out.strip()} at module level"


# -- deploy/compose-entrypoint.sh, run with a stand-in `hercs` that prints its arguments --------

def run_entrypoint(tmp_path: Path, args: list[str], **env: str) -> subprocess.CompletedProcess[str]:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    fake = bin_dir / "hercs"
    fake.write_text('#!/bin/sh\nfor a in "$@"; do printf "%s\\n" "$a"; done\n')
    fake.chmod(0o755)
    environ = {"PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", **env}
    return subprocess.run(["sh", str(REPO / "deploy" / "compose-entrypoint.sh"), *args],
                          capture_output=True, text=True, env=environ, timeout=30, check=False)


def test_entrypoint_passes_hercs_set_as_separate_overrides(tmp_path: Path) -> None:
    done = run_entrypoint(tmp_path, ["learner", "--run", "r", "--run-dir", str(tmp_path)],
                          HERCS_SET=" training.cycles_per_epoch=2\tview.save=* ")
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["learner", "--run", "r", "--run-dir", str(tmp_path),
                                        "--set", "training.cycles_per_epoch=2",
                                        "--set", "view.save=*"]  # never globbed
    done = run_entrypoint(tmp_path, ["router", "--listen", "tls/0.0.0.0:7447"])
    assert done.stdout.splitlines() == ["router", "--listen", "tls/0.0.0.0:7447"]


@pytest.mark.parametrize("leftover", ["metrics.csv", "checkpoints/learner.pt"])
def test_entrypoint_refuses_a_run_that_already_trained(tmp_path: Path, leftover: str) -> None:
    run = tmp_path / "runs" / "compose"
    (run / leftover).parent.mkdir(parents=True)
    args = ["--run-dir", str(tmp_path / "runs"), "--run", "compose"]
    for role in ("replay", "learner"):
        assert run_entrypoint(tmp_path, [role, *args]).returncode == 0, "a new run starts"
    (run / leftover).write_text("epoch,success_rate\n1,0.5\n")
    for role in ("replay", "learner"):
        done = run_entrypoint(tmp_path, [role, *args])
        assert done.returncode == 2, role
        assert done.stdout == "", f"{role}: hercs must not start"
        assert "run 'compose' already exists" in done.stderr
        assert "HERCS_RUN=" in done.stderr and "HERCS_RESUME=1" in done.stderr
        resumed = run_entrypoint(tmp_path, [role, *args], HERCS_RESUME="1")
        assert resumed.returncode == 0 and resumed.stdout.splitlines()[0] == role
    # the other roles never decide about the run folder
    for role in ("clusterer", "evaluator", "actor"):
        assert run_entrypoint(tmp_path, [role, *args]).returncode == 0, role
