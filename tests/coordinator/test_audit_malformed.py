"""An audit request that does not decode is answered saying why, as any other request is: on its
reply topic when its request id and reply_to can still be read, on `errors` always."""

from __future__ import annotations

import json
from typing import Any

import pytest

from gridfleet.grid import GridMap
from gridfleet.protocol import Topics

from support.coordinator_drive import answered, make_core
from support.effects import header_json

T = Topics("gridfleet")
GRID = GridMap.from_rows(["...."], name="yard")


def ask(kind: str, payload: bytes) -> dict[str, list[dict[str, Any]]]:
    """What the coordinator publishes for `payload` on `requests/<kind>`, parsed, by topic."""
    published, effects = answered(make_core(GRID), T.request(kind), payload)
    out: dict[str, list[dict[str, Any]]] = {}
    for o in published:
        out.setdefault(o.topic, []).append(json.loads(o.payload))
    assert effects.audit.entries == ()
    return out


def body(**fields: object) -> bytes:
    return json.dumps({"header": header_json("operator-cli", 0), **fields}).encode()


@pytest.mark.parametrize(
    ("fields", "why"),
    [
        ({"since": 7}, "since"),  # a number for a time
        ({"since": "2026-11-21T09:00:00Z", "limit": "100"}, "limit"),  # a string for a number
        ({"since": "2026-11-21T09:00:00Z", "actor": ["ann"]}, "actor"),
        ({}, "since"),  # missing
    ],
)
def test_an_audit_query_of_wrong_types_is_refused_on_its_reply_topic(
    fields: dict[str, object], why: str
) -> None:
    # As found: only an error report without a request id; `gridfleet audit` waited it out.
    out = ask("audit", body(request_id="q-1", reply_to="operator-cli", **fields))
    (page,) = out[T.audit_reply("operator-cli")]
    assert (page["request_id"], page["accepted"], page["entries"]) == ("q-1", False, [])
    assert page["reason"].startswith("AuditQuery: field '") and why in page["reason"]
    (error,) = out[T.fleet("errors")]
    assert (error["request_id"], error["reason"]) == ("q-1", page["reason"])


def test_a_login_report_of_wrong_types_is_refused_on_its_reply_topic() -> None:
    out = ask("audit_login", body(request_id="l-1", reply_to="dashboard-1", event="hacked"))
    (reply,) = out[T.reply("dashboard-1")]
    assert (reply["request_id"], reply["accepted"]) == ("l-1", False)
    assert reply["reason"].startswith("AuditLogin: field 'event'")
    assert [e["request_id"] for e in out[T.fleet("errors")]] == ["l-1"]


@pytest.mark.parametrize(
    "payload",
    [
        b"{not json",
        b"[]",
        b'{"request_id": 7, "reply_to": "operator-cli"}',  # no request id to answer
        b'{"request_id": "q-1", "reply_to": "no such/topic"}',  # no topic to answer on
        b"\xff\xfe",
        b'{"request_id": "q-1", "reply_to": "operator-cli", "x": ' + b"[" * 5000 + b"]" * 5000,
    ],
)
def test_an_audit_request_with_no_reply_address_gets_an_error_report(payload: bytes) -> None:
    out = ask("audit", payload)
    assert list(out) == [T.fleet("errors")]
    (error,) = out[T.fleet("errors")]
    assert error["topic"] == T.request("audit") and error["reason"].startswith("AuditQuery: ")
    assert error["request_id"] == (
        "q-1" if payload.startswith(b'{"request_id": "q-1", "reply_to": "no such') else None
    )
