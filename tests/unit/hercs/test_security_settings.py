"""The pure parts of hercs.net.security: settings per role, refusals, the access-control table."""

from __future__ import annotations

from pathlib import Path

import pytest

from hercs.config import SecurityConfig
from hercs.errors import ConfigError
from hercs.net.security import ROLE_GRANTS, access_control, is_loopback, zenoh_settings
from hercs.roles import ROLES

TLS = "transport/link/tls/"


def _files(tmp_path: Path, *names: str) -> None:
    for name in names:
        (tmp_path / name).write_text("x")


def test_each_process_uses_its_roles_certificate(tmp_path: Path) -> None:
    _files(tmp_path, "ca.pem", "router.pem", "router.key", "actor.pem", "actor.key")
    sec = SecurityConfig(tls_ca=str(tmp_path / "ca.pem"), tls_cert=str(tmp_path / "{role}.pem"),
                         tls_key=str(tmp_path / "{role}.key"))
    client = zenoh_settings(sec, mode="client", role="actor", endpoints=["tls/h:1"])
    assert client[TLS + "connect_certificate"] == str(tmp_path / "actor.pem")
    assert client[TLS + "enable_mtls"] is True and "access_control" not in client
    router = zenoh_settings(sec, mode="router", role=None, endpoints=["tls/0.0.0.0:1"])
    assert router[TLS + "listen_private_key"] == str(tmp_path / "router.key")
    assert router["access_control"]["default_permission"] == "deny"
    with pytest.raises(ConfigError, match="tls/HOST:PORT"):
        zenoh_settings(sec, mode="client", role="actor", endpoints=["tcp/h:1"])
    with pytest.raises(ConfigError, match="not a readable file"):
        zenoh_settings(sec, mode="client", role="learner", endpoints=["tls/h:1"])
    with pytest.raises(ConfigError, match="all three"):
        zenoh_settings(SecurityConfig(tls_ca=sec.tls_ca), mode="client", role="actor",
                       endpoints=["tls/h:1"])


def test_credentials_pick_the_roles_line(tmp_path: Path) -> None:
    path = tmp_path / "users.txt"
    path.write_text("# users\nactor:a-secret\nlearner:l-secret\n")
    sec = SecurityConfig(credentials=str(path))
    got = zenoh_settings(sec, mode="client", role="learner", endpoints=["tcp/h:1"])
    assert got["transport/auth/usrpwd/user"] == "learner"
    assert got["transport/auth/usrpwd/password"] == "l-secret"
    with pytest.raises(ConfigError, match="no line for user 'replay'"):
        zenoh_settings(sec, mode="client", role="replay", endpoints=["tcp/h:1"])
    router = zenoh_settings(sec, mode="router", role=None, endpoints=["tcp/127.0.0.1:1"])
    assert router["transport/auth/usrpwd/dictionary_file"] == str(path)
    assert router["access_control"]["subjects"][0] == {"id": "replay", "usernames": ["replay"]}
    path.write_text("actor-without-password\n")
    with pytest.raises(ConfigError, match=r"users.txt:1 is not 'user:password'"):
        zenoh_settings(sec, mode="router", role=None, endpoints=["tcp/127.0.0.1:1"])


def test_access_control_grants_weights_only_to_the_learner() -> None:
    acl = access_control(by_certificate=True, by_user=False)
    rules = {rule["id"]: rule for rule in acl["rules"]}
    publishers = set()
    for policy in acl["policies"]:
        (role,) = policy["subjects"]
        for rule_id in policy["rules"]:
            rule = rules[rule_id]
            if "put" in rule["messages"] and rule["flows"] == ["ingress"] \
                    and "hercs/*/weights" in rule["key_exprs"]:
                publishers.add(role)
    assert publishers == {"learner"}
    assert set(ROLE_GRANTS) == set(ROLES)
    assert len(rules) == len(acl["rules"]), "rule ids are unique (zenoh refuses duplicates)"


@pytest.mark.parametrize(("endpoint", "loopback"), [
    ("tcp/127.0.0.1:7447", True), ("tcp/127.8.0.1:7447", True), ("tcp/[::1]:7447", True),
    ("tcp/localhost:7447", True), ("tcp/0.0.0.0:7447", False), ("tls/10.0.0.2:7447", False),
    ("tcp/learner.lab:7447", False)])
def test_loopback(endpoint: str, loopback: bool) -> None:
    assert is_loopback(endpoint) is loopback
