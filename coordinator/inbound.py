"""What the coordinator reads: the topics it follows, and each payload decoded and validated.

Pure. A payload that is not valid raises ProtocolError naming the problem (the caller reports it
on `errors`); a topic the coordinator does not read is nobody's error here.
"""

from __future__ import annotations

from dataclasses import dataclass

from gridfleet.errors import ProtocolError
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    CancelJob,
    ClearObstacles,
    CloseZone,
    Connection,
    ControlUnit,
    Factsheet,
    JobHistoryQuery,
    OpenZone,
    RemoveUnit,
    SetGoal,
    SubmitJob,
    Topics,
    UnitState,
    codec,
    decode,
)
from gridfleet.protocol.constants import MAX_REQUEST_BYTES
from gridfleet.protocol.messages import AuditLogin, AuditQuery
from gridfleet.protocol.stop import STOP_KINDS, stop_filters

Request = (
    SubmitJob
    | CancelJob
    | SetGoal
    | ControlUnit
    | ClearObstacles
    | RemoveUnit
    | CloseZone
    | OpenZone
)


@dataclass(frozen=True)
class StopPayload:
    """A payload on a stop topic (the latch or a press), read by the core's StopView."""

    payload: bytes


Query = JobHistoryQuery | AuditQuery | AuditLogin
Message = Connection | Factsheet | UnitState | StopPayload | Request | Query

_FROM_UNITS: dict[str, type[Connection] | type[Factsheet] | type[UnitState]] = {
    "connection": Connection,
    "factsheet": Factsheet,
    "state": UnitState,
}
_REQUESTS: dict[str, type[Request]] = {
    "submit_job": SubmitJob,
    "cancel_job": CancelJob,
    "set_goal": SetGoal,
    "control_unit": ControlUnit,
    "clear_obstacles": ClearObstacles,
    "remove_unit": RemoveUnit,
    "close_zone": CloseZone,
    "open_zone": OpenZone,
}
# The records' requests: pages answered from the stores (records.py) and the dashboard's login
# reports; no job changes, and no answer is kept for a retry.
_QUERIES: dict[str, type[Query]] = {
    "job_history": JobHistoryQuery,
    "audit": AuditQuery,
    "audit_login": AuditLogin,
}


@dataclass(frozen=True)
class Arrival:
    """One decoded message: its kind, the unit it came from (unit topics) and the message."""

    kind: str
    unit: str | None
    message: Message


def subscriptions(topics: Topics) -> list[tuple[str, int]]:
    """Every filter the coordinator follows, with the QoS it subscribes at."""
    out = [(topics.all_units(kind), SUBSCRIBE_QOS) for kind in _FROM_UNITS]
    out += stop_filters(topics)
    out.append((topics.all_requests, SUBSCRIBE_QOS))
    # Its own status comes back every few seconds: hearing nothing, not even that, the
    # coordinator knows the silence is its own link's, not its units' (world.py, heard).
    out.append((topics.fleet("coordinator"), SUBSCRIBE_QOS))
    return out


def reply_address(topics: Topics, topic: str, payload: bytes) -> tuple[str | None, str | None]:
    """(request id, reply_to) of a refused request, each None where it cannot be read."""
    try:
        kind, _ = topics.parse(topic)
    except ProtocolError:
        return None, None
    if kind not in _REQUESTS and kind not in _QUERIES:
        return None, None
    return codec.reply_address(payload)


def read(topics: Topics, topic: str, payload: bytes) -> Arrival | None:
    """The message on `topic`; None for a topic the coordinator does not read."""
    try:
        kind, ident = topics.parse(topic)
    except ProtocolError:
        return None  # not ours to judge
    if kind in _FROM_UNITS and ident is not None:
        return Arrival(kind, ident, decode(_FROM_UNITS[kind], payload))
    if kind in STOP_KINDS:
        return Arrival(kind, ident, StopPayload(payload))
    if kind in _REQUESTS:
        return Arrival(kind, None, decode(_REQUESTS[kind], payload, MAX_REQUEST_BYTES))
    if kind in _QUERIES:
        return Arrival(kind, None, decode(_QUERIES[kind], payload, MAX_REQUEST_BYTES))
    return None
