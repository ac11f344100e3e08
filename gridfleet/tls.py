"""TLS server contexts: the broker's listeners and the dashboard's HTTPS serve the same files."""

from __future__ import annotations

import ssl
from pathlib import Path

from gridfleet.errors import ConfigError


def server_context(cert: str | Path, key: str | Path) -> ssl.SSLContext:
    """A TLS server context serving `cert` with `key`, asking clients for no certificate.

    ConfigError naming the file when one is missing, unreadable or not a certificate and its key.
    """
    for path, what in ((cert, "certificate"), (key, "key")):
        try:
            Path(path).read_bytes()
        except FileNotFoundError:
            raise ConfigError(f"{path}: no such TLS {what} file") from None
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read the TLS {what}: {exc}") from None
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    try:
        context.load_cert_chain(cert, key)
    except ssl.SSLError as exc:
        raise ConfigError(
            f"{cert} and {key}: not a PEM certificate and its private key ({exc.reason})"
        ) from None
    # amqtt asks every client for a certificate (CERT_OPTIONAL); a browser's wss then fails
    # (measured with Chromium). Clients are known by their accounts, not by certificates.
    context.verify_mode = ssl.CERT_NONE
    return context
