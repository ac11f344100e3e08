"""The audit trail's pure parts: entries made by the coordinator core, its pages and login
reports, the store, the broker gate's check of the latch, and the command line's time ranges."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from gridfleet.accounts import Account, Accounts, rules
from gridfleet.broker.gate import Gate
from gridfleet.console.audit import parse_time, print_csv, print_table, time_range
from gridfleet.coordinator.audit import AuditLog, Identity
from gridfleet.coordinator.audit_store import AuditStore
from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.records import RecordQuery
from gridfleet.coordinator.world import World
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import CancelJob, ControlUnit, SubmitJob, Topics, encode
from gridfleet.protocol.messages import AuditEntry, AuditLogin, AuditQuery, LoginEvent

from support.coordinator_drive import AuditRows, answered
from support.effects import FIXED, header, stamper

T = Topics("gridfleet")
PASSWORD = "p" * 16
ACCOUNTS = Accounts(
    {
        a.name: a
        for a in (
            Account("coordinator", PASSWORD, "coordinator"),
            Account("operator", PASSWORD, "operator"),
            Account("ann", PASSWORD, "operator"),
            Account("dashboard", PASSWORD, "dashboard"),
            Account("viewer", PASSWORD, "viewer"),
            Account("unit1", PASSWORD, "unit", "unit1"),
            Account("device-unit1", PASSWORD, "device", "unit1"),
        )
    }
)
VOUCHED = Identity(ACCOUNTS, vouched=True)


def core(identity: Identity | None = None) -> CoordinatorCore:
    """A core on an empty 4x3 map, every header at FIXED."""
    grid = GridMap.from_rows(["....", "....", "...."], name="yard")
    return CoordinatorCore(
        World(grid, step_period_s=1.0, fleet_known_after_s=0.0),
        JobBook(),
        nonce="n",
        topics=T,
        stamp=stamper("coordinator"),
        identity=identity,
    )


def entries(c: CoordinatorCore, topic: str, payload: bytes) -> list[dict[str, object]]:
    """The audit entries one message makes, as JSON."""
    effects = c.on_message(topic, payload, 0.0)
    return [json.loads(e.model_dump_json()) for e in effects.audit.entries]


def submit(sender: str, request_id: str = "r-1", mass: float = 1.0) -> bytes:
    return encode(
        SubmitJob(
            header=header(sender),
            request_id=request_id,
            reply_to=sender,
            pickup=Cell(0, 0),
            dropoff=Cell(3, 2),
            mass_kg=mass,
            job_id="j1",
        )
    )


AT = "2026-11-21T10:00:00Z"


def test_a_request_is_recorded_with_the_account_owning_its_sender() -> None:
    c = core(VOUCHED)
    assert entries(c, T.request("submit_job"), submit("ann-cli-1a2b3c")) == [
        {
            "at": AT,
            "actor": "ann",
            "verified": True,
            "via": "ann-cli-1a2b3c",
            "act": "submit_job",
            "target": "j1",
            "detail": "1 kg, [0, 0] -> [3, 2], priority 0",
            "outcome": "accepted",
            "reason": None,
        }
    ]
    # A retry (same sender, id and content) is the same act: not recorded again.
    assert entries(c, T.request("submit_job"), submit("ann-cli-1a2b3c")) == []


def test_a_refused_request_is_recorded_as_refused_with_the_reason() -> None:
    c = core(VOUCHED)
    cancel = CancelJob(header=header("operator"), request_id="r-2", job_id="nope")
    (entry,) = entries(c, T.request("cancel_job"), encode(cancel))
    assert (entry["actor"], entry["act"], entry["target"], entry["outcome"], entry["reason"]) == (
        "operator",
        "cancel_job",
        "nope",
        "refused",
        "unknown job 'nope'",
    )
    pause = ControlUnit(header=header("operator"), request_id="r-3", unit="u9", command="pause")
    (entry,) = entries(c, T.request("control_unit"), encode(pause))
    assert (entry["act"], entry["target"], entry["reason"]) == ("pause", "u9", "unknown unit 'u9'")


def test_without_accounts_or_a_vouching_broker_the_sender_is_recorded_as_claimed() -> None:
    (open_broker,) = entries(core(), T.request("submit_job"), submit("admin"))
    assert (open_broker["actor"], open_broker["verified"]) == ("admin", False)
    (mosquitto,) = entries(core(Identity(ACCOUNTS)), T.request("submit_job"), submit("operator-x"))
    assert (mosquitto["actor"], mosquitto["verified"], mosquitto["via"]) == (
        "operator",
        False,
        "operator-x",
    )


def test_the_stop_is_recorded_once_per_act_not_per_copy() -> None:
    c = core(VOUCHED)
    latch, press = T.fleet("estop"), T.device("device_stop", "device-unit1")
    assert entries(c, press, b"engaged|device-unit1|button") == [
        {
            "at": AT,
            "actor": "device-unit1",
            "verified": True,
            "via": "device-unit1",
            "act": "stop_engage",
            "target": "device-unit1",
            "detail": "button",
            "outcome": "accepted",
            "reason": None,
        }
    ]
    # The coordinator's copy of the press on the latch, read back: the press's act, not another.
    assert entries(c, latch, b"engaged|device-unit1|button") == []
    (release,) = entries(c, latch, b"released|operator-cli-9|area checked")
    assert (release["actor"], release["act"], release["via"], release["detail"]) == (
        "operator",
        "stop_release",
        "operator-cli-9",
        "area checked",
    )
    assert entries(c, press, b"") == []  # cleared by the coordinator after the release
    (again,) = entries(c, latch, b"engaged|ann-page-1|STOP pressed")
    assert (again["actor"], again["act"]) == ("ann", "stop_engage")


def test_a_restart_replaying_the_retained_stop_records_nothing_new() -> None:
    first = core(VOUCHED)
    latch = T.fleet("estop")
    seen = first.on_message(latch, b"engaged|operator|pressed", 0.0).audit.seen
    assert seen == ((latch, b"engaged|operator|pressed"),)
    second = core(VOUCHED)
    second.audit.restore(seen)
    assert entries(second, latch, b"engaged|operator|pressed") == []
    (changed,) = entries(second, latch, b"released|operator|done")
    assert changed["act"] == "stop_release"


def entry(minutes: int, actor: str) -> AuditEntry:
    return AuditEntry(
        at=FIXED - timedelta(minutes=minutes),
        actor=actor,
        verified=True,
        act="pause",
        target="unit1",
        outcome="accepted",
    )


def ask(c: CoordinatorCore, reader: AuditRows, sender: str, **fields: Any) -> dict[str, Any]:
    query = AuditQuery(header=header(sender), request_id="q-1", reply_to=sender, **fields)
    out, _ = answered(c, T.request("audit"), encode(query), reader)
    (page,) = [o for o in out if o.topic == T.audit_reply(sender)]
    data: dict[str, Any] = json.loads(page.payload)
    return data


def test_the_audit_pages_oldest_first_with_a_cursor() -> None:
    reader = AuditRows(
        [entry(50, "ann"), entry(40, "operator"), entry(30, "ann"), entry(20, "ann")]
    )
    desk = core(VOUCHED)
    since = FIXED - timedelta(hours=1)
    first = ask(desk, reader, "ann-cli", since=since, actor="ann", limit=2)
    assert first["accepted"] is True and first["next_cursor"] == "3"
    assert [e["at"] for e in first["entries"]] == [
        "2026-11-21T09:10:00Z",
        "2026-11-21T09:30:00Z",
    ]
    rest = ask(desk, reader, "ann-cli", since=since, actor="ann", limit=2, cursor="3")
    assert [e["at"] for e in rest["entries"]] == ["2026-11-21T09:40:00Z"]
    assert rest["next_cursor"] is None
    window = ask(desk, reader, "operator", since=since, until=FIXED - timedelta(minutes=35))
    assert len(window["entries"]) == 2


def test_the_audit_refuses_a_range_backwards_or_empty_and_a_viewer() -> None:
    # The records' one range rule (records.range_problem), the job history's too.
    desk = core(VOUCHED)
    before = FIXED - timedelta(seconds=1)
    backwards = ask(desk, AuditRows(), "operator", since=FIXED, until=before)
    assert backwards["accepted"] is False
    assert (
        backwards["reason"] == "since 2026-11-21T10:00:00Z is not before until 2026-11-21T09:59:59Z"
    )
    empty = ask(desk, AuditRows([entry(0, "ann")]), "operator", since=FIXED, until=FIXED)
    assert (empty["accepted"], empty["entries"]) == (False, [])
    # A time without a zone is UTC (§1), as it always was here.
    naive_since = (FIXED - timedelta(minutes=2)).replace(tzinfo=None)
    naive = ask(desk, AuditRows([entry(1, "ann")]), "operator", since=naive_since)
    assert (naive["accepted"], len(naive["entries"])) == (True, 1)
    viewer = ask(desk, AuditRows([entry(1, "ann")]), "viewer-x", since=FIXED - timedelta(hours=1))
    assert (viewer["accepted"], viewer["entries"]) == (False, [])
    assert viewer["reason"] == (
        "viewer-x is a viewer account's client: only operator and dashboard accounts may read "
        "the audit"
    )


def login(sender: str, event: LoginEvent, user: str | None, request_id: str = "l-1") -> bytes:
    return encode(
        AuditLogin(
            header=header(sender),
            request_id=request_id,
            reply_to=sender,
            event=event,
            user=user,
            address="10.0.0.7",
            reason="wrong user name or password" if event == "login_failed" else None,
        )
    )


def test_only_the_dashboard_reports_logins_and_a_retry_is_stored_once() -> None:
    desk = core(VOUCHED)
    topic = T.request("audit_login")
    ok = desk.on_message(topic, login("dashboard-audit-1", "login", "ann"), 0.0)
    assert [json.loads(e.model_dump_json()) for e in ok.audit.entries] == [
        {
            "at": AT,
            "actor": "ann",
            "verified": True,
            "via": "dashboard",
            "act": "login",
            "target": None,
            "detail": "from 10.0.0.7",
            "outcome": "accepted",
            "reason": None,
        }
    ]
    again = desk.on_message(topic, login("dashboard-audit-1", "login", "ann"), 0.0)
    assert again.audit.entries == () and json.loads(again.publish[0].payload)["accepted"] is True
    failed = desk.on_message(topic, login("dashboard-audit-1", "login_failed", "bob", "l-2"), 0.0)
    (bad,) = failed.audit.entries
    assert (bad.actor, bad.verified, bad.outcome, bad.reason) == (
        "bob",
        False,
        "refused",
        "wrong user name or password",
    )
    forged = desk.on_message(topic, login("operator", "login", "ann", "l-3"), 0.0)
    assert forged.audit.entries == ()
    refusal = json.loads(forged.publish[-1].payload)
    assert (refusal["reason"], refusal["code"]) == (
        "operator is an operator account's client: only dashboard accounts may report logins",
        "forbidden",
    )


def test_the_store_pages_prunes_and_keeps_what_it_has_across_a_reopen(tmp_path: Path) -> None:
    db = tmp_path / "c.sqlite3"
    store = AuditStore(db, keep_days=1)
    store.add([entry(60 * 30, "old"), entry(10, "ann"), entry(5, "operator")])
    store.save_seen([(T.fleet("estop"), b"engaged|operator|x")])
    assert store.prune(FIXED.timestamp()) == 1
    store.close()
    again = AuditStore(db, keep_days=1)

    def span(**fields: Any) -> RecordQuery:
        query = AuditQuery(
            header=header("t"), request_id="q", since=FIXED - timedelta(days=2), **fields
        )
        return RecordQuery.of("audit", query, FIXED)

    assert [(i, e.actor) for i, e in again.rows(span(), 10)] == [(2, "ann"), (3, "operator")]
    assert [i for i, _ in again.rows(span(actor="operator"), 10)] == [3]
    assert again.rows(span(cursor="2"), 10)[0][0] == 3
    assert again.load_seen() == [(T.fleet("estop"), b"engaged|operator|x")]
    again.close()
    with pytest.raises(ValueError, match="give more than 0"):
        AuditStore(db, keep_days=0)


def test_the_gate_drops_a_latch_naming_another_accounts_id() -> None:
    gate, latch = Gate(ACCOUNTS), T.fleet("estop")
    assert gate.refused_publish("operator", "operator-1", latch, b"engaged|operator-1|x") is None
    assert gate.refused_publish("operator", "operator-1", latch, b"released|admin|x") == (
        "its latch names 'admin', an id account 'operator' does not own"
    )
    # The coordinator copies presses and restores the latch under the cause's own name.
    assert gate.refused_publish("coordinator", "coordinator", latch, b"engaged|unit1|x") is None
    # An audit login report names its sender like any request.
    report = login("operator", "login", "ann").replace(b'"operator"', b'"dashboard"', 1)
    assert gate.refused_publish("operator", "operator", T.request("audit_login"), report) == (
        "its header names sender 'dashboard', an id account 'operator' does not own"
    )


def test_only_people_ask_for_the_audit_and_only_the_dashboard_reports_logins() -> None:
    def may(name: str) -> tuple[bool, bool, bool]:
        r = rules(ACCOUNTS.get(name), T)
        return (
            T.request("audit") in r.publish,
            T.request("audit_login") in r.publish,
            any(f.startswith(f"{T.prefix}/audit") or f == f"{T.prefix}/#" for f in r.subscribe),
        )

    assert may("operator") == (True, False, True)
    assert may("dashboard") == (True, True, True)
    assert may("viewer") == (False, False, False)
    assert may("unit1") == (False, False, False)


NOW = datetime(2026, 11, 26, 15, 0, tzinfo=UTC)


def test_times_read_as_local_unless_they_name_their_zone_or_a_span_back_from_now() -> None:
    # One rule with `gridfleet job history` (gridfleet.options.moment): a person reads a clock.
    local = datetime(2026, 11, 26, 14, 2).astimezone()
    assert parse_time("2026-11-26T14:02", NOW, "--since") == local
    assert parse_time("2026-11-26", NOW, "--since") == datetime(2026, 11, 26).astimezone()
    assert parse_time("2026-11-26T14:02Z", NOW, "--since") == datetime(
        2026, 11, 26, 14, 2, tzinfo=UTC
    )
    assert parse_time("2026-11-26T15:02+01:00", NOW, "--since") == datetime(
        2026, 11, 26, 14, 2, tzinfo=UTC
    )
    assert parse_time("now", NOW, "--until") == NOW
    assert parse_time("90m", NOW, "--since") == datetime(2026, 11, 26, 13, 30, tzinfo=UTC)
    assert parse_time("7d", NOW, "--since") == datetime(2026, 11, 19, 15, 0, tzinfo=UTC)


@pytest.mark.parametrize(
    ("since", "until", "message"),
    [
        (
            "yesterday",
            None,
            "--since 'yesterday' is not a time: give an ISO 8601 time or date, local unless it "
            "names its zone (2026-11-26T14:02, 2026-11-26, 2026-11-26T14:02Z), now, or a span "
            "back from now (90s, 30m, 24h, 7d)",
        ),
        (
            "2026-11-26T14:00Z",
            "2026-11-26T13:00Z",
            "--since 2026-11-26T14:00:00+00:00 is after --until 2026-11-26T13:00:00+00:00: "
            "nothing can lie between",
        ),
        (
            "2026-11-27T00:00Z",
            None,
            "--since 2026-11-27T00:00:00+00:00 is after now (2026-11-26T15:00:00+00:00): "
            "nothing can lie between",
        ),
    ],
)
def test_a_bad_range_is_refused_in_one_line(since: str, until: str | None, message: str) -> None:
    with pytest.raises(ConfigError) as refused:
        time_range(since, until, NOW)
    assert str(refused.value) == message


def test_the_table_marks_claimed_actors_and_the_csv_has_every_field() -> None:
    import io

    rows = [entry(1, "ann"), AuditEntry(**{**entry(0, "admin").model_dump(), "verified": False})]
    table = io.StringIO()
    print_table(rows, table)
    assert table.getvalue().splitlines() == [
        "at (UTC)                 actor            act             target           outcome",
        "2026-11-21T09:59:00.000Z ann              pause           unit1            accepted",
        "2026-11-21T10:00:00.000Z admin?           pause           unit1            accepted",
        "? not vouched for: what the client claimed, or the name typed at a failed login",
    ]
    out = io.StringIO()
    print_csv(rows[:1], out)
    assert out.getvalue().splitlines() == [
        "at,actor,verified,via,act,target,detail,outcome,reason",
        "2026-11-21T09:59:00.000Z,ann,True,,pause,unit1,,accepted,",
    ]


def test_an_audit_log_without_identity_records_claims() -> None:
    log = AuditLog()
    log.stop(FIXED, "estop", None, T.fleet("estop"), b"engaged|someone|x")
    (e,) = log.take().entries
    assert (e.actor, e.verified) == ("someone", False)
