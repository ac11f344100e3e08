"""The accounts file of the aedes launcher (broker/aedes/launcher.mjs) from gridfleet accounts,
with the same rules as the embedded broker's (`gridfleet.accounts.rules`): users with PBKDF2
hashes of their passwords (never the passwords) and the topic filters each may publish to and
subscribe to."""

from __future__ import annotations

import base64
import hashlib
import json
import os
import secrets
from pathlib import Path
from typing import Any

from gridfleet.accounts import Accounts, rules
from gridfleet.protocol import Topics

# PBKDF2-SHA512: what node's crypto.pbkdf2 checks at each CONNECT, in its thread pool. 10 000
# rounds take about 10 ms of a core: a fleet's reconnections after an instance's death (every
# client of it at once) stay quick; the accounts file is private (mode 600) all the same.
ALGORITHM = "pbkdf2-sha512"
ITERATIONS = 10_000
LAUNCHER = Path(__file__).resolve().parent / "aedes" / "launcher.mjs"
ACCOUNTS_FILE = "aedes-accounts.json"


def password_hash(password: str, salt: bytes | None = None) -> dict[str, Any]:
    """The launcher's record of `password`: algorithm, rounds, salt and digest (base64)."""
    salt = salt or secrets.token_bytes(16)
    digest = hashlib.pbkdf2_hmac("sha512", password.encode(), salt, ITERATIONS)
    b64 = base64.b64encode
    return {
        "algorithm": ALGORITHM,
        "iterations": ITERATIONS,
        "salt": b64(salt).decode(),
        "digest": b64(digest).decode(),
    }


def accounts_json(accounts: Accounts, topics: Topics) -> dict[str, Any]:
    """The launcher's accounts file: per account its password hash and topic filters."""
    users = {}
    for account in accounts.accounts.values():
        allowed = rules(account, topics)
        users[account.name] = {
            "role": account.role,
            "hash": password_hash(account.password),
            "publish": list(allowed.publish),
            "subscribe": list(allowed.subscribe),
        }
    return {
        "generated_by": "gridfleet accounts aedes; edit the accounts file instead",
        "root": topics.root,
        "users": users,
    }


def write_accounts_json(accounts: Accounts, topics: Topics, directory: Path) -> Path:
    """Write the launcher's accounts file (owner-readable only) into `directory`; its path."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / ACCOUNTS_FILE
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as out:
        os.fchmod(fd, 0o600)  # a file that was there keeps its mode through O_TRUNC
        json.dump(accounts_json(accounts, topics), out, indent=2)
        out.write("\n")
    return path


def launcher_command(
    accounts_file: Path | None,
    *,
    redis_url: str = "redis://127.0.0.1:6379",
    host: str = "127.0.0.1",
    port: int = 1883,
    ws_port: int | None = 9001,
    instance_id: str | None = None,
    heartbeat_ms: int | None = None,
    node: str = "node",
) -> list[str]:
    """The command that runs one aedes instance of a cluster on the Redis at `redis_url`."""
    command = [node, str(LAUNCHER), "--redis", redis_url, "--host", host, "--port", str(port)]
    if ws_port is not None:
        command += ["--ws-port", str(ws_port)]
    if instance_id is not None:
        command += ["--id", instance_id]
    if heartbeat_ms is not None:
        command += ["--heartbeat-interval", str(heartbeat_ms)]
    if accounts_file is not None:
        command += ["--accounts", str(accounts_file)]
    return command
