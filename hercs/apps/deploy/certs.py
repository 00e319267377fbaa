"""`hercs certs DIR`: a CA and the certificates of a secured run (docs/SECURITY.md).

Writes into DIR, never overwriting a file: `ca.pem`/`ca.key`, `router.pem`/`router.key`
(serverAuth; SANs: the --host names plus localhost and 127.0.0.1), one `<role>.pem`/`.key` per
role (clientAuth; common name = the role, which access control matches) and, with
--credentials, `credentials.txt` (a random password per role). Keys are ECDSA P-256, as rustls
(Zenoh's TLS) requires; mode 0600. Keep `ca.key` off the hosts.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
import secrets
from collections.abc import Sequence
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from hercs.errors import ConfigError
from hercs.net.security import ROUTER_NAME
from hercs.roles import ROLES

VALID_DAYS = 825
"""Validity of every certificate made here (about 27 months)."""


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "hercs"),
                      x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _builder(subject: x509.Name, issuer: x509.Name,
             key: ec.EllipticCurvePrivateKey) -> x509.CertificateBuilder:
    now = dt.datetime.now(dt.UTC)
    return (x509.CertificateBuilder().subject_name(subject).issuer_name(issuer)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=VALID_DAYS))
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()),
                           critical=False))


def _san(hosts: Sequence[str]) -> x509.SubjectAlternativeName:
    names: list[x509.GeneralName] = []
    for host in dict.fromkeys([*hosts, "localhost", "127.0.0.1"]):
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host.strip("[]"))))
        except ValueError:
            names.append(x509.DNSName(host))
    return x509.SubjectAlternativeName(names)


def _write(path: Path, data: bytes, *, private: bool) -> None:
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL
    fd = os.open(path, flags, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def make_certs(out: str | os.PathLike[str], *, hosts: Sequence[str] = (),
               roles: Sequence[str] = ROLES, credentials: bool = False) -> list[Path]:
    """Write the CA, the router's and each role's certificate and key into `out`; returns
    the files written. Refuses (ConfigError) to overwrite anything."""
    out = Path(out)
    unknown = sorted(set(roles) - set(ROLES))
    if unknown:
        raise ConfigError(f"hercs certs: unknown roles {unknown}; known: {list(ROLES)}")
    names = ["ca", ROUTER_NAME, *roles]
    planned = [out / f"{n}.{ext}" for n in names for ext in ("pem", "key")]
    if credentials:
        planned.append(out / "credentials.txt")
    existing = [str(p) for p in planned if p.exists()]
    if existing:
        raise ConfigError(f"hercs certs: {existing} already exist; pick an empty folder "
                          "(certificates are never overwritten)")
    out.mkdir(parents=True, exist_ok=True)

    ca_key = _key()
    ca_name = _name("hercs CA")
    ca = (_builder(ca_name, ca_name, ca_key)
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True,
                                       crl_sign=True, content_commitment=False,
                                       key_encipherment=False, data_encipherment=False,
                                       key_agreement=False, encipher_only=False,
                                       decipher_only=False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    pem = serialization.Encoding.PEM
    key_format = (pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    _write(out / "ca.pem", ca.public_bytes(pem), private=False)
    _write(out / "ca.key", ca_key.private_bytes(*key_format), private=True)

    leaf_usage = x509.KeyUsage(digital_signature=True, key_encipherment=False,
                               content_commitment=False, data_encipherment=False,
                               key_agreement=True, key_cert_sign=False, crl_sign=False,
                               encipher_only=False, decipher_only=False)
    for name in [ROUTER_NAME, *roles]:
        key = _key()
        usage = [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH] \
            if name == ROUTER_NAME else [ExtendedKeyUsageOID.CLIENT_AUTH]
        builder = (_builder(_name(name), ca_name, key)
                   .add_extension(x509.BasicConstraints(ca=False, path_length=None),
                                  critical=True)
                   .add_extension(leaf_usage, critical=True)
                   .add_extension(x509.ExtendedKeyUsage(usage), critical=False)
                   .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(
                       ca_key.public_key()), critical=False)
                   .add_extension(_san(hosts) if name == ROUTER_NAME
                                  else x509.SubjectAlternativeName([x509.DNSName(name)]),
                                  critical=False))
        cert = builder.sign(ca_key, hashes.SHA256())
        _write(out / f"{name}.pem", cert.public_bytes(pem), private=False)
        _write(out / f"{name}.key", key.private_bytes(*key_format), private=True)
    if credentials:
        lines = "".join(f"{role}:{secrets.token_urlsafe(18)}\n" for role in roles)
        _write(out / "credentials.txt", lines.encode(), private=True)
    return planned


def run_certs(out: str, *, hosts: Sequence[str], credentials: bool) -> int:
    written = make_certs(out, hosts=hosts, credentials=credentials)
    print(f"hercs certs: wrote {len(written)} files to {out}; keep ca.key off the run's hosts. "
          f"Router: --tls-ca {out}/ca.pem --tls-cert {out}/router.pem --tls-key "
          f"{out}/router.key --listen tls/0.0.0.0:7447; an actor on another host: --tls-ca "
          f"ca.pem --tls-cert actor.pem --tls-key actor.key --connect tls/ROUTER_HOST:7447")
    return 0
