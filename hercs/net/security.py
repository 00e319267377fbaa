"""Who may join a run and what each role may do: Zenoh TLS, user/password and access control.
Each process authenticates as its role (`hercs.roles`) by a certificate named for the role, a
`user:password` line, or both; the router denies by default and grants each role only its own
keys (`ROLE_GRANTS`: an actor can insert episodes and read weights, but cannot publish
weights, models or results nor serve a replay key). A router listening beyond loopback without
TLS is refused (`listen_problem`) unless `security.allow_insecure`. Threat model:
docs/SECURITY.md; the Zenoh settings and ACL semantics this rests on (eclipse-zenoh 1.10.2) are
noted at `zenoh_settings` and `access_control`."""

from __future__ import annotations

import ipaddress
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hercs.config import SecurityConfig, endpoint_parts
from hercs.errors import ConfigError
from hercs.proto.keys import ROOT

ROUTER_NAME = "router"
"""The common name of the router's certificate (its SAN carries its addresses)."""

ROLE_PLACEHOLDER = "{role}"
"""In `security.tls_cert`/`tls_key`, replaced by the process's role (`router` for the
router): one config serves every process of `hercs up` (`--tls-dir DIR`)."""

_ANY = f"{ROOT}/**"
"""Declarations a publisher or querier must learn of, on any hercs key: a wildcard subscriber
(the launcher's `metrics/**`) is only announced to a publisher allowed a key that includes
it. Knowing that a subscriber or queryable exists grants nothing."""

_GRANTS: dict[str, list[tuple[list[str], list[str], str | None]]] = {
    # (messages, flows, key override) each kind of use needs, seen from the router
    "publish": [(["put", "delete"], ["ingress"], None),
                (["declare_subscriber"], ["egress"], _ANY)],
    "subscribe": [(["declare_subscriber"], ["ingress"], None),
                  (["put", "delete"], ["egress"], None)],
    "query": [(["query"], ["ingress"], None), (["reply"], ["egress"], None),
              (["declare_queryable"], ["egress"], _ANY)],
    "serve": [(["declare_queryable", "reply"], ["ingress"], None),
              (["query"], ["egress"], None)],
    "token": [(["liveliness_token"], ["ingress"], None)],
    "watch": [(["declare_liveliness_subscriber", "liveliness_query"], ["ingress"], None),
              (["liveliness_token"], ["egress"], None)],
    # An advanced publisher's cache answers a late joiner's query on `<key>/@adv/...` with
    # the cached sample, whose key is the plain `<key>`: the reply needs its own grant.
    "answer_cached": [(["reply"], ["ingress"], None)],
    "receive_cached": [(["reply"], ["egress"], None)],
}

_ADV = "@adv/**"
"""zenoh-ext's advanced publisher/subscriber (latest value for late joiners) talk on
`<key>/@adv/...`: a cache queryable and liveliness tokens for publisher detection."""


def _run_key(suffix: str) -> str:
    return f"{ROOT}/*/{suffix}"


def _latest_publish(suffix: str) -> list[tuple[str, list[str]]]:
    """A `publisher(latest=True)`: puts, its cache queryable and its liveliness token."""
    adv = _run_key(f"{suffix}/{_ADV}")
    return [("publish", [_run_key(suffix)]), ("serve", [adv]), ("token", [adv]),
            ("watch", [adv]), ("answer_cached", [_run_key(suffix)])]


def _latest_subscribe(suffix: str) -> list[tuple[str, list[str]]]:
    """A `subscribe(latest=True)`: the puts, a query of the publishers' caches, and watching
    for publishers (and their own detection token)."""
    adv = _run_key(f"{suffix}/{_ADV}")
    return [("subscribe", [_run_key(suffix)]), ("subscribe", [adv]), ("query", [adv]),
            ("watch", [adv]), ("receive_cached", [_run_key(suffix)])]


def _common(role: str) -> list[tuple[str, list[str]]]:
    """What every service does: its liveliness token and its metrics."""
    return [("token", [_run_key(f"alive/{role}/*")]),
            ("publish", [_run_key(f"metrics/{role}")])]


def _joiner() -> list[tuple[str, list[str]]]:
    """Processes that join a run with only --connect and --run: the run's config, and which
    runs exist (named when the run is not found)."""
    return [("query", [_run_key("config")]), ("watch", [_run_key("alive/replay/*")])]


ROLE_GRANTS: dict[str, list[tuple[str, list[str]]]] = {
    "replay": [
        *_common("replay"),
        ("serve", [_run_key(k) for k in ("replay/insert", "replay/sample", "replay/episode",
                                          "replay/clusterer_state", "replay/status_at",
                                          "config")]),
        ("publish", [_run_key("replay/inserted"), _run_key("replay/status")]),
        *_latest_subscribe("cluster/model"),
        ("subscribe", [_run_key("eval/result")]),
    ],
    "learner": [
        *_common("learner"),
        ("query", [_run_key("replay/sample"), _run_key("replay/status_at")]),
        *_latest_publish("weights"),
        *_latest_publish("run/progress"),
        ("publish", [_run_key("eval/request")]),
        ("subscribe", [_run_key("eval/result"), _run_key("replay/status")]),
    ],
    "clusterer": [
        *_common("clusterer"),
        *_latest_publish("cluster/model"),
        ("subscribe", [_run_key("replay/inserted")]),
        ("query", [_run_key("replay/clusterer_state")]),
    ],
    "evaluator": [
        *_common("evaluator"),
        ("publish", [_run_key("eval/result")]),
        *_latest_subscribe("weights"),
        ("subscribe", [_run_key("eval/request")]),
    ],
    "actor": [
        *_common("actor"),
        *_joiner(),
        ("query", [_run_key("replay/insert")]),
        *_latest_subscribe("weights"),
        *_latest_subscribe("run/progress"),
    ],
    "live": [
        *_common("live"),
        *_joiner(),
        ("subscribe", [_run_key("replay/inserted"), _run_key("metrics/**"),
                       _run_key("replay/status")]),
        *_latest_subscribe("cluster/model"),
        ("query", [_run_key("replay/episode")]),
    ],
}
"""What each role may do, by key (under any run). Nothing else is allowed."""


def access_control(*, by_certificate: bool, by_user: bool) -> dict[str, Any]:
    """The router's `access_control` section: deny by default, `ROLE_GRANTS` per role. A
    client is matched by its certificate's common name and/or its user name (both must
    equal the role when both are configured).

    Zenoh's ACL (1.10.2, verified on loopback): flows are seen from the router (ingress:
    client → router); a rule grants the product of its messages and flows, so each grant is
    split by flow (`_GRANTS`); a declared publisher also needs `declare_subscriber` egress and
    a declared querier `declare_queryable` egress (both learn their matches); the verbatim
    `@adv` chunk of zenoh-ext's advanced publisher keys is matched by no `**`, so those keys
    are granted explicitly (`_ADV`). Denied messages are dropped by the router silently."""
    if not (by_certificate or by_user):
        raise ValueError("access control needs an identity: certificates or users")
    rules: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    for role, grants in ROLE_GRANTS.items():
        rule_ids = []
        for n, (use, keys) in enumerate(grants):
            for m, (messages, flows, any_key) in enumerate(_GRANTS[use]):
                rule_id = f"{role}.{n}.{use}.{m}"
                rules.append({"id": rule_id, "permission": "allow", "messages": messages,
                              "flows": flows, "key_exprs": [any_key] if any_key else keys})
                rule_ids.append(rule_id)
        subject: dict[str, Any] = {"id": role}
        if by_certificate:
            subject["cert_common_names"] = [role]
        if by_user:
            subject["usernames"] = [role]
        subjects.append(subject)
        policies.append({"id": f"{role}.policy", "rules": rule_ids, "subjects": [role]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def read_credentials(path: str) -> dict[str, str]:
    """`user:password` lines (blank lines and `#` comments skipped)."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ConfigError(f"security.credentials: cannot read {path!r} ({exc})") from None
    users: dict[str, str] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        user, sep, password = line.partition(":")
        if not sep or not user or not password:
            raise ConfigError(f"security.credentials: {path}:{n} is not 'user:password'")
        users[user] = password
    if not users:
        raise ConfigError(f"security.credentials: {path} holds no 'user:password' line")
    return users


def _readable(what: str, path: str) -> str:
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"security.{what}: {path!r} is not a readable file (see "
                          "docs/SECURITY.md; `hercs certs DIR` makes a CA and certificates)")
    return str(p.resolve())


def zenoh_settings(security: SecurityConfig, *, mode: str, role: str | None,
                   endpoints: Sequence[str]) -> dict[str, Any]:
    """The Zenoh config entries (`insert_json5` key → value) that `security` asks for, for a
    router (`mode='router'`) or a client of `role`.

    The TLS keys (eclipse-zenoh 1.10.2) are `transport/link/tls/{root_ca_certificate,
    listen_certificate, listen_private_key, connect_certificate, connect_private_key,
    enable_mtls}`; a client must set `enable_mtls` too, or it does not present its
    certificate."""
    settings: dict[str, Any] = {}
    tls = bool(security.tls_cert or security.tls_key or security.tls_ca)
    if tls:
        if not (security.tls_cert and security.tls_key and security.tls_ca):
            raise ConfigError("security: TLS needs all three of tls_cert, tls_key and tls_ca "
                              f"(got cert={security.tls_cert!r}, key={security.tls_key!r}, "
                              f"ca={security.tls_ca!r})")
        plain = [e for e in endpoints if not e.startswith(("tls/", "quic/"))]
        if plain:
            raise ConfigError(f"transport: with TLS configured every endpoint must be tls/HOST:PORT"
                              f"; got {plain}")
        side = "listen" if mode == "router" else "connect"
        me = ROUTER_NAME if mode == "router" else (role or "")
        settings["transport/link/tls/root_ca_certificate"] = _readable("tls_ca", security.tls_ca)
        settings[f"transport/link/tls/{side}_certificate"] = _readable(
            "tls_cert", security.tls_cert.replace(ROLE_PLACEHOLDER, me))
        settings[f"transport/link/tls/{side}_private_key"] = _readable(
            "tls_key", security.tls_key.replace(ROLE_PLACEHOLDER, me))
        settings["transport/link/tls/enable_mtls"] = True
    if security.credentials:
        if mode == "router":
            read_credentials(security.credentials)  # refuse a malformed file before Zenoh does
            settings["transport/auth/usrpwd/dictionary_file"] = _readable(
                "credentials", security.credentials)
        else:
            users = read_credentials(security.credentials)
            if role in users:
                user = role
            elif len(users) == 1:
                (user,) = users
            else:
                raise ConfigError(f"security.credentials: {security.credentials} has no line for "
                                  f"user {role!r} and more than one line to choose from")
            settings["transport/auth/usrpwd/user"] = user
            settings["transport/auth/usrpwd/password"] = users[user]
    if mode == "router" and (tls or security.credentials) and security.access_control:
        settings["access_control"] = access_control(by_certificate=tls,
                                                    by_user=bool(security.credentials))
    return settings


def is_loopback(endpoint: str) -> bool:
    host = endpoint_parts(endpoint)[1]
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def listen_problem(security: SecurityConfig, listen: Sequence[str]) -> str | None:
    """Why a router may not listen on `listen` with `security`, or None: an address other
    hosts can reach needs TLS, unless `allow_insecure` says the network is trusted."""
    exposed = [e for e in listen if not is_loopback(e)]
    if not exposed or security.tls_cert or security.allow_insecure:
        return None
    return (f"the router would listen on {exposed}, reachable from other hosts, with no "
            "authentication: anyone who reaches the port could read the run and publish "
            "weights. Give --tls-ca/--tls-cert/--tls-key (`hercs certs DIR` makes them; see "
            "docs/SECURITY.md) and listen on tls/HOST:PORT, or on a network you trust add "
            "--set security.allow_insecure=true")
