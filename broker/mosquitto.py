"""Mosquitto's password and ACL files from gridfleet accounts, with the same rules as the embedded
broker's (`gridfleet.accounts.rules`): one accounts file serves either broker."""

from __future__ import annotations

import base64
import hashlib
import os
import pwd
import secrets
from dataclasses import dataclass
from pathlib import Path

from gridfleet.accounts import Account, Accounts, bridge_topics, rules
from gridfleet.broker.limits import Limits
from gridfleet.protocol import Topics

# Mosquitto counts a late subscriber's retained replay against max_queued_messages, and drops a
# QoS 0 delivery (every gridfleet subscription: protocol.md §2) once that many packets wait for
# the client: 500 units' records are 1,500 retained messages, and past 1,000 a page had no map.
# The count is set past any fleet's replay; max_queued_bytes (32 MiB) still bounds what a client
# that does not read costs.
MOSQUITTO_QUEUED_MESSAGES = 100_000
DEFAULT_LIMITS = Limits(max_queued_messages=MOSQUITTO_QUEUED_MESSAGES)
ITERATIONS = 101  # mosquitto_passwd's default for its $7$ (PBKDF2-SHA512) hashes
# Started as root, Mosquitto drops to this user (its default `user`) before it opens its password,
# ACL, TLS key and persistence files; started as anyone else, it stays that user.
MOSQUITTO_USER = "mosquitto"


@dataclass(frozen=True)
class RunAs:
    """The user Mosquitto runs as: it reads passwd, acl and any TLS key, and writes its data."""

    name: str
    uid: int
    gid: int


def runs_as() -> RunAs | None:
    """Whom Mosquitto will run as from files written now: user `mosquitto` when this runs as root
    (it drops to that user), else this user; None as root with no user `mosquitto` (or a uid with
    no name)."""
    try:
        entry = pwd.getpwnam(MOSQUITTO_USER) if os.geteuid() == 0 else pwd.getpwuid(os.geteuid())
    except KeyError:
        return None
    return RunAs(entry.pw_name, entry.pw_uid, entry.pw_gid)


def hand_over(path: Path | int, owner: RunAs | None) -> None:
    """Make `path` (or an open file descriptor) `owner`'s, user and group, when this runs as root;
    anyone else's files are theirs already. Mosquitto 2 warns of a password or ACL file whose
    owner or group is not its own, or that others may read, and says later versions refuse it."""
    if owner is not None and os.geteuid() == 0:
        os.chown(path, owner.uid, owner.gid)


def write_conf(path: Path, text: str, owner: RunAs | None) -> None:
    """Write mosquitto.conf where only Mosquitto may read it (a bridge's `remote_password` is in
    it): as root, root's with `owner`'s group and mode 640 (Mosquitto reads it as root, and again
    as its own user on SIGHUP, but may not rewrite what root reads); else this user's, 600."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as out:
        os.fchmod(fd, 0o600)  # a file that was there keeps its mode through O_TRUNC
        if owner is not None and os.geteuid() == 0:
            os.fchown(fd, 0, owner.gid)
            os.fchmod(fd, 0o640)
        out.write(text)


def _allowed(owner: RunAs, groups: set[int], st: os.stat_result, want: int) -> bool:
    """Whether `owner` (in `groups`) may `want` (os.R_OK, W_OK, X_OK bits) by `st`'s mode bits."""
    if owner.uid == 0:
        return True
    shift = 6 if st.st_uid == owner.uid else 3 if st.st_gid in groups else 0
    return (st.st_mode >> shift) & want == want


def _whose(st: os.stat_result) -> str:
    """`owner NAME, mode 700` of a stat result."""
    try:
        name = pwd.getpwuid(st.st_uid).pw_name
    except KeyError:
        name = str(st.st_uid)
    return f"owner {name}, mode {st.st_mode & 0o7777:o}"


def blocked(owner: RunAs, path: Path, write: bool = False) -> str | None:
    """Why `owner` cannot read (or, `write`, create files in) `path`, by the mode bits of it and
    of every folder above it (ACLs aside); None when it can."""
    groups = set(os.getgrouplist(owner.name, owner.gid))
    path = path.resolve()
    for folder in reversed(path.parents):
        st = folder.stat()
        if not _allowed(owner, groups, st, os.X_OK):
            return f"cannot enter {folder} ({_whose(st)})"
    st = path.stat()
    if not _allowed(owner, groups, st, os.W_OK | os.X_OK if write else os.R_OK):
        return f"cannot {'write in' if write else 'read'} {path} ({_whose(st)})"
    return None


def password_hash(password: str, salt: bytes | None = None) -> str:
    """A Mosquitto `$7$` hash of `password`, as `mosquitto_passwd` writes it."""
    salt = salt or secrets.token_bytes(12)
    digest = hashlib.pbkdf2_hmac("sha512", password.encode(), salt, ITERATIONS)
    b64 = base64.b64encode
    return f"$7${ITERATIONS}${b64(salt).decode()}${b64(digest).decode()}"


def password_file(accounts: Accounts) -> str:
    """Mosquitto's `password_file`: `name:<hash>` per account."""
    return "".join(f"{a.name}:{password_hash(a.password)}\n" for a in accounts.accounts.values())


def acl_file(accounts: Accounts, topics: Topics) -> str:
    """Mosquitto's `acl_file`: per account, the topics it may read and write."""
    lines = ["# generated by 'gridfleet accounts mosquitto'; edit the accounts file instead", ""]
    for account in accounts.accounts.values():
        allowed = rules(account, topics)
        lines.append(f"user {account.name}")
        lines += [f"topic write {t}" for t in allowed.publish]
        lines += [f"topic read {t}" for t in allowed.subscribe]
        lines.append("")
    return "\n".join(lines)


def write_files(
    accounts: Accounts, topics: Topics, directory: Path, owner: RunAs | None = None
) -> tuple[Path, Path]:
    """Write `passwd` and `acl` (owner-readable only, `owner`'s when run as root) into
    `directory`; their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in (("passwd", password_file(accounts)), ("acl", acl_file(accounts, topics))):
        path = directory / name
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            os.fchmod(fd, 0o600)  # a file that was there keeps its mode through O_TRUNC
            hand_over(fd, owner)
            out.write(text)
        written.append(path)
    return written[0], written[1]


def mosquitto_conf(
    password_file: Path,
    acl_file: Path,
    *,
    host: str = "127.0.0.1",
    port: int = 1883,
    ws_port: int | None = 9001,
    tls_cert: Path | None = None,
    tls_key: Path | None = None,
    persistence_dir: Path | None = None,
    limits: Limits = DEFAULT_LIMITS,
    user: str | None = None,
) -> str:
    """The `mosquitto.conf` for a gridfleet fleet: accounts only, and the embedded broker's limits.

    `user`: whom Mosquitto drops to when started as root (the owner of passwd, acl and the
    persistence folder); None leaves Mosquitto's default, user mosquitto.
    """
    # persistence_dir None: nothing survives a restart of Mosquitto, the latched emergency stop (a
    # retained message) included; a directory keeps retained messages across restarts.
    tls = tls_cert is not None and tls_key is not None
    lines = [
        "# gridfleet fleet broker (broker/mosquitto.py); passwd and acl: 'gridfleet accounts "
        "mosquitto'",
        "per_listener_settings false",
        "allow_anonymous false",
        "# Small packets go out at once: with Nagle's algorithm a unit's state, then its direction,",
        "# waits for a delayed ACK (~40 ms) and the fleet's step rate halves (docs/brokers.md).",
        "set_tcp_nodelay true",
        *(
            [
                "# Started as root, Mosquitto drops to this user, who owns passwd, acl and the",
                "# persistence folder (and reads them); started as anyone else, it stays that user.",
                f"user {user}",
            ]
            if user is not None
            else []
        ),
        f"password_file {password_file}",
        f"acl_file {acl_file}",
        "# Client ids: these files cannot bind them to accounts, so any account may take over any",
        "# client's connection (the embedded broker refuses it). use_username_as_clientid would",
        "# stop that, but an account's several clients would then kick each other (docs/brokers.md).",
        "",
    ]
    listeners: list[tuple[int, list[str]]] = [(port, [])]
    if ws_port is not None:
        listeners.append((ws_port, ["protocol websockets"]))
    for number, extra in listeners:
        lines += [f"listener {number} {host}", *extra]
        if tls:
            lines += [f"certfile {tls_cert}", f"keyfile {tls_key}"]
    lines += [
        "",
        "# The protocol's largest message is a retained fleet view of 8 MiB (protocol.md). A bigger",
        "# packet disconnects its sender, as on the embedded broker (message_size_limit would drop",
        "# it and keep the connection; one behaviour for both brokers).",
        f"max_packet_size {limits.max_packet_bytes}",
        "# A client that does not read: past these its messages are dropped, as on the embedded",
        "# broker.",
        f"max_queued_messages {limits.max_queued_messages}",
        f"max_queued_bytes {limits.max_queued_bytes}",
        "",
    ]
    if persistence_dir is None:
        lines += [
            "# Nothing survives a restart: not even a latched emergency stop (retained).",
            "persistence false",
        ]
    else:
        lines += [
            "# Retained messages (the latched emergency stop among them) survive a restart: saved",
            "# on SIGTERM, every autosave_interval seconds and on SIGUSR1; a kill -9 or a power cut",
            "# loses what changed since the last save (at most the last minute).",
            "persistence true",
            f"persistence_location {str(persistence_dir).rstrip('/')}/",
            "autosave_interval 60",
        ]
    return "\n".join(lines) + "\n"


# A bridge notices a dead central broker by its own keep-alive, as every gridfleet client does.
BRIDGE_KEEP_ALIVE_S = 10


def bridge_conf(
    account: Account,
    central_host: str,
    central_port: int,
    topics: Topics,
    ca_file: Path | None = None,
) -> str:
    """The `connection` section that bridges a hall's Mosquitto to the central broker.

    It logs in there as the `bridge` account `account` and carries `bridge_topics` (see
    docs/brokers.md). Its session outlives a cut (`cleansession false`): what each side sent
    at QoS 1 meanwhile is delivered when the link is back, and the retained latch is read again.
    With `ca_file` it speaks TLS, trusting that CA and checking the central broker's name.
    """
    if account.role != "bridge":
        raise ValueError(f"account {account.name} is a {account.role} account, not a bridge")
    lines = [
        "",
        "# The bridge to the central broker (coordinator and people there, units and devices here):",
        "# generated by 'gridfleet accounts mosquitto --bridge-to'.",
        f"connection {account.name}",
        f"address {central_host}:{central_port}",
        f"remote_username {account.name}",
        f"remote_password {account.password}",
        f"remote_clientid {account.name}",
        "bridge_protocol_version mqttv311",
        "# Queued both ways across a cut; the central broker does not echo back what came from it.",
        "cleansession false",
        "try_private true",
        f"keepalive_interval {BRIDGE_KEEP_ALIVE_S}",
        "# Back within seconds of the link: 1 s after a cut, then up to 10 s apart.",
        "restart_timeout 1 10",
        "notifications false",
    ]
    if ca_file is not None:
        # The bridge's password crosses the site's network: only to the broker the CA vouches
        # for, under the name it was reached by (bridge_insecure false checks the name).
        lines += [f"bridge_cafile {ca_file}", "bridge_insecure false"]
    lines += [f"topic {b.pattern} {b.direction} {b.qos}" for b in bridge_topics(topics)]
    return "\n".join(lines) + "\n"
