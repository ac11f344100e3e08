"""Topic names of the protocol and what travels on each (QoS, retained, payload type)."""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from typing import Literal

from gridfleet.errors import ProtocolError
from gridfleet.protocol.constants import (
    DEFAULT_ROOT,
    ID_PATTERN,
    MAX_DEVICE_CONNECTION_BYTES,
    MAX_DIRECTION_BYTES,
    MAX_ESTOP_BYTES,
    MAX_ID_CHARS,
    MAX_REQUEST_BYTES,
    MAX_VIEW_BYTES,
    ROOT_SEGMENT_PATTERN,
    TOPIC_VERSION,
)

_ID_RE = re.compile(ID_PATTERN)
_ROOT_SEGMENT_RE = re.compile(ROOT_SEGMENT_PATTERN)

Payload = Literal["json", "direction", "estop", "device_connection"]


def validate_id(value: str, what: str = "id") -> str:
    """Return `value` when it is a valid unit/job/client id, else raise ProtocolError naming it."""
    if not isinstance(value, str) or not _ID_RE.fullmatch(value):
        raise ProtocolError(
            f"{what} {value!r} is not a valid id: 1-64 characters of letters, digits, '_', '.', '-',"
            " starting with a letter or digit"
        )
    return value


@dataclass(frozen=True)
class TopicSpec:
    """How one kind of topic is used: pattern, QoS, retained flag, payload and size limit."""

    kind: str
    pattern: str  # relative to the prefix; {unit} / {kind} / {client} are placeholders
    qos: int
    retained: bool
    payload: Payload
    model: str | None  # name of the message model in gridfleet.protocol.messages
    max_bytes: int


TOPICS: dict[str, TopicSpec] = {
    spec.kind: spec
    for spec in (
        TopicSpec(
            "connection",
            "units/{unit}/connection",
            1,
            True,
            "json",
            "Connection",
            MAX_REQUEST_BYTES,
        ),
        TopicSpec(
            "factsheet", "units/{unit}/factsheet", 1, True, "json", "Factsheet", MAX_REQUEST_BYTES
        ),
        TopicSpec("state", "units/{unit}/state", 0, True, "json", "UnitState", MAX_REQUEST_BYTES),
        TopicSpec(
            "vehicle",
            "units/{unit}/vehicle",
            1,
            True,
            "json",
            "VehicleCondition",
            MAX_REQUEST_BYTES,
        ),
        TopicSpec("order", "units/{unit}/order", 1, False, "json", "Order", MAX_REQUEST_BYTES),
        TopicSpec("goal", "units/{unit}/goal", 1, False, "json", "Goal", MAX_REQUEST_BYTES),
        TopicSpec(
            "direction", "units/{unit}/direction", 0, True, "direction", None, MAX_DIRECTION_BYTES
        ),
        TopicSpec("stop", "units/{unit}/stop", 1, True, "estop", None, MAX_ESTOP_BYTES),
        TopicSpec("estop", "fleet/estop", 1, True, "estop", None, MAX_ESTOP_BYTES),
        TopicSpec("map", "fleet/map", 1, True, "json", "FleetMap", MAX_VIEW_BYTES),
        TopicSpec("jobs", "fleet/jobs", 1, True, "json", "JobsView", MAX_VIEW_BYTES),
        TopicSpec("routes", "fleet/routes", 0, True, "json", "Routes", MAX_VIEW_BYTES),
        TopicSpec("events", "fleet/events", 1, True, "json", "EventsView", MAX_VIEW_BYTES),
        TopicSpec("energy", "fleet/energy", 1, True, "json", "EnergyView", MAX_VIEW_BYTES),
        TopicSpec("zones", "fleet/zones", 1, True, "json", "ZonesView", MAX_VIEW_BYTES),
        TopicSpec(
            "submit_job", "requests/submit_job", 1, False, "json", "SubmitJob", MAX_REQUEST_BYTES
        ),
        TopicSpec(
            "cancel_job", "requests/cancel_job", 1, False, "json", "CancelJob", MAX_REQUEST_BYTES
        ),
        TopicSpec("set_goal", "requests/set_goal", 1, False, "json", "SetGoal", MAX_REQUEST_BYTES),
        TopicSpec(
            "control_unit",
            "requests/control_unit",
            1,
            False,
            "json",
            "ControlUnit",
            MAX_REQUEST_BYTES,
        ),
        TopicSpec(
            "clear_obstacles",
            "requests/clear_obstacles",
            1,
            False,
            "json",
            "ClearObstacles",
            MAX_REQUEST_BYTES,
        ),
        TopicSpec(
            "remove_unit",
            "requests/remove_unit",
            1,
            False,
            "json",
            "RemoveUnit",
            MAX_REQUEST_BYTES,
        ),
        TopicSpec(
            "close_zone", "requests/close_zone", 1, False, "json", "CloseZone", MAX_REQUEST_BYTES
        ),
        TopicSpec(
            "open_zone", "requests/open_zone", 1, False, "json", "OpenZone", MAX_REQUEST_BYTES
        ),
        TopicSpec(
            "ack_alert", "requests/ack_alert", 1, False, "json", "AckAlert", MAX_REQUEST_BYTES
        ),
        TopicSpec("alerts", "fleet/alerts", 1, True, "json", "AlertsView", MAX_VIEW_BYTES),
        TopicSpec("audit", "requests/audit", 1, False, "json", "AuditQuery", MAX_REQUEST_BYTES),
        TopicSpec(
            "audit_login",
            "requests/audit_login",
            1,
            False,
            "json",
            "AuditLogin",
            MAX_REQUEST_BYTES,
        ),
        TopicSpec(
            "audit_reply", "audit/replies/{client}", 1, False, "json", "AuditPage", MAX_VIEW_BYTES
        ),
        TopicSpec(
            "job_history",
            "requests/job_history",
            1,
            False,
            "json",
            "JobHistoryQuery",
            MAX_REQUEST_BYTES,
        ),
        TopicSpec(
            "history_reply",
            "history/replies/{client}",
            1,
            False,
            "json",
            "JobHistoryPage",
            MAX_VIEW_BYTES,
        ),
        TopicSpec("revoke", "broker/revoke", 1, False, "json", "BrokerRevoke", MAX_REQUEST_BYTES),
        TopicSpec("reply", "replies/{client}", 1, False, "json", "Reply", MAX_REQUEST_BYTES),
        TopicSpec("errors", "errors", 1, False, "json", "ErrorReport", MAX_REQUEST_BYTES),
        TopicSpec(
            "coordinator",
            "coordinator/status",
            1,
            True,
            "json",
            "CoordinatorStatus",
            MAX_REQUEST_BYTES,
        ),
        TopicSpec(
            "device_connection",
            "devices/{device}/connection",
            1,
            True,
            "device_connection",
            None,
            MAX_DEVICE_CONNECTION_BYTES,
        ),
        TopicSpec("device_stop", "devices/{device}/stop", 1, True, "estop", None, MAX_ESTOP_BYTES),
    )
}

_UNIT_KINDS = {k for k, s in TOPICS.items() if s.pattern.startswith("units/")}
# A device topic's last level -> its kind (devices/<device>/stop is `device_stop`).
_DEVICE_KINDS = {
    s.pattern.rsplit("/", 1)[1]: k for k, s in TOPICS.items() if s.pattern.startswith("devices/")
}


class Topics:
    """Topic names under one root, e.g. `gridfleet/v1/units/unit1/state`."""

    def __init__(self, root: str = DEFAULT_ROOT) -> None:
        segments = root.split("/")
        if not all(_ROOT_SEGMENT_RE.fullmatch(s) for s in segments):
            raise ProtocolError(
                f"topic root {root!r} is not valid: '/'-separated segments of letters, digits,"
                " '_', '.', '-' (no wildcards, no '$', no empty segment)"
            )
        self.root = root
        self.prefix = f"{root}/{TOPIC_VERSION}"

    def client_id(self, name: str) -> str:
        """An MQTT client id for the one `name` of this root's fleet (e.g. its coordinator).

        Client ids are broker-wide: two fleets sharing a broker under two roots, each with a
        client `coordinator`, would take each other's connection over and over. The default root
        keeps the bare name; another root is added to it (hashed when that would be too long).
        """
        if self.root == DEFAULT_ROOT:
            return name
        tag = self.root.replace("/", ".")
        full = f"{name}@{tag}"
        if len(full) <= MAX_ID_CHARS:
            return full
        digest = hashlib.sha256(self.root.encode()).hexdigest()[:12]
        return f"{name}@{tag[: MAX_ID_CHARS - len(name) - 14]}~{digest}"

    def unit(self, kind: str, unit: str) -> str:
        """The per-unit topic of `kind` (connection, factsheet, state, order, goal, direction, stop)."""
        if kind not in _UNIT_KINDS:
            raise ProtocolError(f"{kind!r} is not a per-unit topic kind")
        return f"{self.prefix}/units/{validate_id(unit, 'unit id')}/{kind}"

    def all_units(self, kind: str) -> str:
        """Wildcard filter for `kind` of every unit."""
        if kind not in _UNIT_KINDS:
            raise ProtocolError(f"{kind!r} is not a per-unit topic kind")
        return f"{self.prefix}/units/+/{kind}"

    def fleet(self, kind: str) -> str:
        """A fleet-wide or coordinator topic: estop, map, jobs, routes, events, errors, coordinator."""
        spec = TOPICS.get(kind)
        if spec is None or "{" in spec.pattern:
            raise ProtocolError(f"{kind!r} is not a fleet-wide topic kind")
        return f"{self.prefix}/{spec.pattern}"

    def request(self, kind: str) -> str:
        """The request topic of `kind` (submit_job, cancel_job, set_goal, control_unit,
        clear_obstacles)."""
        spec = TOPICS.get(kind)
        if spec is None or not spec.pattern.startswith("requests/"):
            raise ProtocolError(f"{kind!r} is not a request kind")
        return f"{self.prefix}/{spec.pattern}"

    def reply(self, client: str) -> str:
        """Where the coordinator answers requests of `client`."""
        return f"{self.prefix}/replies/{validate_id(client, 'client id')}"

    def audit_reply(self, client: str) -> str:
        """Where the coordinator answers `client`'s audit queries (apart from `replies/`: a
        viewer may read replies, not the audit)."""
        return f"{self.prefix}/audit/replies/{validate_id(client, 'client id')}"

    def history_reply(self, client: str) -> str:
        """Where the coordinator answers `client`'s job history queries (pages are large: apart
        from the small replies on `replies/`)."""
        return f"{self.prefix}/history/replies/{validate_id(client, 'client id')}"

    def device(self, kind: str, device: str) -> str:
        """A per-device topic (device_connection, device_stop): plain text, for firmware."""
        spec = TOPICS.get(kind)
        if spec is None or not spec.pattern.startswith("devices/"):
            raise ProtocolError(f"{kind!r} is not a per-device topic kind")
        return f"{self.prefix}/{spec.pattern.format(device=validate_id(device, 'device id'))}"

    def all_devices(self, kind: str) -> str:
        """Wildcard filter for `kind` of every device."""
        spec = TOPICS.get(kind)
        if spec is None or not spec.pattern.startswith("devices/"):
            raise ProtocolError(f"{kind!r} is not a per-device topic kind")
        return f"{self.prefix}/{spec.pattern.format(device='+')}"

    @property
    def all_requests(self) -> str:
        """Wildcard filter for every request kind."""
        return f"{self.prefix}/requests/+"

    def parse(self, topic: str) -> tuple[str, str | None]:
        """Split a topic under this root into (kind, unit or client id); ProtocolError if unknown."""
        if not topic.startswith(self.prefix + "/"):
            raise ProtocolError(f"topic {topic!r} is not under {self.prefix}/")
        rest = topic[len(self.prefix) + 1 :].split("/")
        if len(rest) == 3 and rest[0] == "units" and rest[2] in _UNIT_KINDS:
            return rest[2], validate_id(rest[1], "unit id")
        if len(rest) == 3 and rest[0] == "devices" and rest[2] in _DEVICE_KINDS:
            return _DEVICE_KINDS[rest[2]], validate_id(rest[1], "device id")
        if len(rest) == 2 and rest[0] == "replies":
            return "reply", validate_id(rest[1], "client id")
        if len(rest) == 3 and rest[:2] == ["audit", "replies"]:
            return "audit_reply", validate_id(rest[2], "client id")
        if len(rest) == 3 and rest[:2] == ["history", "replies"]:
            return "history_reply", validate_id(rest[2], "client id")
        joined = "/".join(rest)
        for kind, spec in TOPICS.items():
            if spec.pattern == joined:
                return kind, None
        raise ProtocolError(f"topic {topic!r} is not a gridfleet topic")
