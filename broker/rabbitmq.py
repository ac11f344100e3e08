"""RabbitMQ's definitions (users, vhost, permissions, topic permissions) and a rabbitmq.conf for
its MQTT plugins from gridfleet accounts, with the same rules as the embedded broker's
(`gridfleet.accounts.rules`): one accounts file serves every broker.

RabbitMQ 3.10's MQTT plugin publishes to the topic exchange `amq.topic` with the MQTT topic as
routing key, each '/' and each '.' made a word separator '.' (so `a/b.c` and `a/b/c` are one
routing key there, and a subscriber is told `a/b/c`); a filter's '+' becomes '*' (one word) and
'#' stays '#' (the rest). Topic permissions are regular expressions on that routing key: `write`
is checked at each PUBLISH (and a will), `read` on a SUBSCRIBE's binding key.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
import secrets
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gridfleet.accounts import Accounts, rules
from gridfleet.protocol import Topics

VHOST = "gridfleet"
EXCHANGE = "amq.topic"
HASHING = "rabbit_password_hashing_sha256"
DEFINITIONS_FILE = "definitions.json"
CONF_FILE = "rabbitmq.conf"
NOTHING = "^(?!)"  # a regular expression no routing key matches
# One word of a routing key ('+'): anything but the separator; not '#', so a subscription to
# `a/#` is not taken for one to `a/+`.
WORD = r"[^.#]*"


def password_hash(password: str, salt: bytes | None = None) -> str:
    """RabbitMQ's rabbit_password_hashing_sha256 hash: base64(salt + sha256(salt + password))."""
    salt = salt or secrets.token_bytes(4)
    return base64.b64encode(salt + hashlib.sha256(salt + password.encode()).digest()).decode()


def routing_words(topic: str) -> list[str]:
    """The words of the routing key RabbitMQ 3.10's MQTT plugin makes of `topic` ('/' and '.'
    both separate words)."""
    return re.split(r"[/.]", topic)


def filter_regex(mqtt_filter: str) -> str:
    """The routing-key pattern (unanchored, no groups captured) of the topics an MQTT filter
    matches; it also matches the binding key of any narrower filter (a SUBSCRIBE's check)."""
    words = routing_words(mqtt_filter)
    out: list[str] = []
    for n, word in enumerate(words):
        if word == "#":  # only ever last: `a/#` is `a` and everything below it
            rest = "(?:\\..*)?" if n else ".*"
            return "\\.".join(out) + rest
        out.append(WORD if word == "+" else re.escape(word))
    return "\\.".join(out)


def filters_regex(filters: Sequence[str]) -> str:
    """One anchored regular expression for a list of MQTT filters (NOTHING for none)."""
    if not filters:
        return NOTHING
    return "^(?:" + "|".join(filter_regex(f) for f in filters) + ")$"


def definitions(accounts: Accounts, topics: Topics, vhost: str = VHOST) -> dict[str, Any]:
    """RabbitMQ's definitions for `accounts`: a user each (hashed password, no tags: no
    management), full permissions in `vhost` (only the MQTT plugins speak there) and topic
    permissions on amq.topic from `rules()`."""
    users, permissions, topic_permissions = [], [], []
    for account in accounts.accounts.values():
        allowed = rules(account, topics)
        users.append(
            {
                "name": account.name,
                "password_hash": password_hash(account.password),
                "hashing_algorithm": HASHING,
                "tags": [],
                "limits": {},
            }
        )
        permissions.append(
            {"user": account.name, "vhost": vhost, "configure": ".*", "write": ".*", "read": ".*"}
        )
        topic_permissions.append(
            {
                "user": account.name,
                "vhost": vhost,
                "exchange": EXCHANGE,
                "write": filters_regex(allowed.publish),
                "read": filters_regex(allowed.subscribe),
            }
        )
    return {
        "rabbit_version": "3.10.8",
        "rabbitmq_version": "3.10.8",
        "users": users,
        "vhosts": [{"name": vhost, "limits": [], "metadata": {"description": "gridfleet"}}],
        "permissions": permissions,
        "topic_permissions": topic_permissions,
        "parameters": [],
        "global_parameters": [],
        "policies": [],
        "queues": [],
        "exchanges": [],
        "bindings": [],
    }


def write_definitions(
    accounts: Accounts, topics: Topics, directory: Path, vhost: str = VHOST
) -> Path:
    """Write definitions.json (owner-readable only: password hashes) into `directory`; its path."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / DEFINITIONS_FILE
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as out:
        os.fchmod(fd, 0o600)  # a file that was there keeps its mode through O_TRUNC
        json.dump(definitions(accounts, topics, vhost), out, indent=2)
        out.write("\n")
    return path


def rabbitmq_conf(
    *,
    host: str = "127.0.0.1",
    port: int = 1883,
    ws_port: int | None = 15675,
    definitions: Path | None = None,
    vhost: str = VHOST,
    peers: Sequence[str] = (),
) -> str:
    """A node's rabbitmq.conf for a gridfleet fleet: MQTT (and MQTT over websockets, path /ws) on
    `host`, no AMQP listener; with `definitions` the accounts of that file and no anonymous
    clients (without: anonymous clients as guest in vhost '/', for tests). `peers`: the nodes
    (`rabbit@host`) it clusters with at its first boot (classic peer discovery)."""
    lines = [
        "# gridfleet fleet broker, one node (broker/rabbitmq.py); 'gridfleet accounts rabbitmq'",
        "# MQTT only: no AMQP listener (accounts are made for MQTT's topic rules alone).",
        "listeners.tcp = none",
        f"mqtt.listeners.tcp.default = {host}:{port}",
        "mqtt.tcp_listen_options.nodelay = true",
        f"mqtt.exchange = {EXCHANGE}",
    ]
    if ws_port is not None:
        lines += [f"web_mqtt.tcp.ip = {host}", f"web_mqtt.tcp.port = {ws_port}"]
    if definitions is not None:
        lines += [
            "mqtt.allow_anonymous = false",
            f"mqtt.vhost = {vhost}",
            f"default_vhost = {vhost}",
            "# The accounts, loaded at each boot (users, vhost, permissions, topic permissions).",
            "definitions.import_backend = local_filesystem",
            f"definitions.local.path = {definitions}",
            "# A persistent session's QoS 1 queue (a hall bridge's, clean session false) is a",
            "# quorum queue: on a majority of the nodes, it outlives the death of one.",
            "mqtt.durable_queue_type = quorum",
        ]
    else:
        lines += ["mqtt.allow_anonymous = true"]
    if peers:
        lines += [
            "cluster_formation.peer_discovery_backend = classic_config",
            *(f"cluster_formation.classic_config.nodes.{n} = {p}" for n, p in enumerate(peers, 1)),
            "# At its first boot, wait up to a minute for the first node to be up.",
            "cluster_formation.discovery_retry_limit = 120",
            "cluster_formation.discovery_retry_interval = 500",
        ]
    return "\n".join(lines) + "\n"
