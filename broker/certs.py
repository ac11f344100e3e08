"""A local certificate authority and the broker's server certificate, for TLS on a LAN.

`make_tls` makes a new CA, signs a server certificate for the given names and addresses with it,
and forgets the CA's key: that CA can then vouch for nothing else. Clients trust `ca.pem`; the
broker serves `server.pem` with `server.key`.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from gridfleet.errors import ConfigError

DEFAULT_HOSTS = ("127.0.0.1", "localhost")
CA_DAYS = 3650
# 825 days: the longest server certificate Apple's TLS clients accept; well within the CA's life.
SERVER_DAYS = 825
FILES = ("ca.pem", "server.pem", "server.key")
_DNS_LABEL = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


@dataclass(frozen=True)
class TlsFiles:
    """The PEM texts of a CA certificate, a server certificate and the server's private key."""

    ca_pem: bytes
    server_pem: bytes
    server_key: bytes


def subject_names(hosts: Sequence[str]) -> list[x509.GeneralName]:
    """The SAN entries for `hosts` (IP addresses and DNS names); ConfigError for a bad one."""
    if not hosts:
        raise ConfigError("give at least one --host the clients connect to")
    names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            address = ipaddress.ip_address(host)
        except ValueError:
            labels = host.rstrip(".").split(".")
            if len(host) > 253 or not all(_DNS_LABEL.fullmatch(label) for label in labels):
                raise ConfigError(
                    f"--host {host!r}: not an IP address or a host name (letters, digits, '-', "
                    "dots)"
                ) from None
            names.append(x509.DNSName(host.rstrip(".").lower()))
            continue
        if address.is_unspecified:
            raise ConfigError(
                f"--host {host}: that is where a broker listens, not an address clients connect "
                "to; give the machine's LAN address (and 127.0.0.1)"
            )
        names.append(x509.IPAddress(address))
        # mbedTLS 2.x (ESP32 Arduino cores before 3.0) matches an address only against DNS
        # names; the same text as a DNS name lets the firmware verify an address too.
        names.append(x509.DNSName(host))
    return names


def make_tls(hosts: Sequence[str] = DEFAULT_HOSTS, now: dt.datetime | None = None) -> TlsFiles:
    """A new CA and a server certificate it signed for `hosts` (P-256 keys, SHA-256)."""
    names = subject_names(hosts)
    start = (now or dt.datetime.now(dt.UTC)) - dt.timedelta(hours=1)  # clock skew
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "gridfleet local CA")])
    ca_cert = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(start + dt.timedelta(days=CA_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(_usage(cert_sign=True), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), False)
        .sign(ca_key, hashes.SHA256())
    )
    key = ec.generate_private_key(ec.SECP256R1())
    first = names[0].value
    server = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, str(first))]))
        .issuer_name(ca_name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(start + dt.timedelta(days=SERVER_DAYS))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(_usage(cert_sign=False), critical=True)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), False
        )
        .sign(ca_key, hashes.SHA256())
    )
    pem = serialization.Encoding.PEM
    return TlsFiles(
        ca_cert.public_bytes(pem),
        server.public_bytes(pem),
        key.private_bytes(pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()),
    )


def _usage(*, cert_sign: bool) -> x509.KeyUsage:
    return x509.KeyUsage(
        digital_signature=not cert_sign,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=cert_sign,
        crl_sign=cert_sign,
        encipher_only=False,
        decipher_only=False,
    )


def write_tls(files: TlsFiles, out: Path, *, force: bool = False) -> list[Path]:
    """Write ca.pem, server.pem and server.key (mode 600) into `out`; the paths written.

    ConfigError when one exists already (unless `force`) or `out` cannot be written.
    """
    paths = [out / name for name in FILES]
    existing = [p for p in paths if p.exists()]
    if existing and not force:
        raise ConfigError(
            f"{existing[0]} exists; --force replaces the CA and certificate (every client then "
            "needs the new ca.pem)"
        )
    texts = (files.ca_pem, files.server_pem, files.server_key)
    try:
        out.mkdir(parents=True, exist_ok=True)
        for path, text, mode in zip(paths, texts, (0o644, 0o644, 0o600), strict=True):
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
            os.fchmod(fd, mode)  # before the key goes in: a replaced file keeps its old mode
            with os.fdopen(fd, "wb") as f:
                f.write(text)
    except OSError as exc:
        raise ConfigError(f"{out}: cannot write the TLS files: {exc}") from None
    return paths
