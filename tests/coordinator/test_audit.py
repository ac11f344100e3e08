"""The audit trail over a real broker with accounts (the embedded amqtt and Mosquitto): each
role's acts recorded with its account, forgeries, a viewer kept out, a restart, the dashboard's
logins, and `gridfleet audit` itself."""

from __future__ import annotations

import asyncio
import csv
import io
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from gridfleet.accounts import Account, Accounts, default_accounts, new_password, write_accounts
from gridfleet.console.audit import read_trail
from gridfleet.coordinator.audit import Identity
from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.audit import LoginReporter
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import CancelJob, SubmitJob, Topics, encode
from gridfleet.protocol.messages import AckAlert, AuditEntry, ErrorReport
from gridfleet.system.threads import ServiceThread

from support.cli import gridfleet
from support.effects import header
from support.mosquitto import broker_with_accounts
from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.security import login
from support.wait import wait_for

pytestmark = pytest.mark.every_broker  # the actor is the account the broker authenticated

ROOT = "audit"
T = Topics(ROOT)
GRID = GridMap.from_rows(["....", "....", "...."], name="yard")
Seen = tuple[str | None, str, str, bool]  # (actor, act, outcome, verified)


@pytest.fixture(scope="module")
def accounts() -> Accounts:
    made = default_accounts(["unit1"])
    made = made.with_account(Account("ann", new_password(), "operator"))
    return made.with_account(Account("vera", new_password(), "viewer"))


@pytest.fixture(scope="module", params=["amqtt", "mosquitto"])
def broker(
    request: pytest.FixtureRequest, accounts: Accounts, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[str, bool]]:
    """(URL without a login, whether the broker vouches for senders) of a broker with accounts."""
    directory = tmp_path_factory.mktemp("mosquitto")
    with broker_with_accounts(request.param, accounts, ROOT, directory) as running:
        yield running


@contextmanager
def coordinator(
    url: str, accounts: Accounts, db: Path, vouched: bool, *, fresh: bool = True
) -> Iterator[ServiceThread[CoordinatorShell]]:
    """A coordinator on its own account, its store at `db`, on a broker with no latch retained.

    A latch left by an earlier test would be an act the new coordinator finds (made while it was
    away, as far as it can tell): recorded. Each test starts without one (`fresh`).
    """
    if fresh:
        with MqttProbe(login(url, accounts, "operator")) as operator:
            operator.publish(T.fleet("estop"), b"", retain=True)

    def make() -> CoordinatorShell:
        return CoordinatorShell(
            login(url, accounts, "coordinator"),
            GRID,
            root=ROOT,
            step_s=0.2,
            db_path=db,
            identity=Identity(accounts, vouched=vouched),
        )

    with ServiceThread(make, "audit-coordinator") as running:
        yield running


@contextmanager
def peer(url: str, accounts: Accounts, account: str, name: str) -> Iterator[OperatorPeer]:
    """An operator peer logged in as `account`, its requests' sender `name`."""
    with MqttProbe(login(url, accounts, account)) as probe:
        yield OperatorPeer(probe, T, name)


def audit(url: str, accounts: Accounts, account: str = "operator") -> list[AuditEntry]:
    """The whole trail of the last hour, read as `account` over the protocol."""
    # A client id of its own each time (read_trail makes one): polling with one id, a new
    # connection took the id from the previous one as it closed, and the broker dropped one.
    since = datetime.now(UTC) - timedelta(hours=1)
    return asyncio.run(read_trail(login(url, accounts, account), T, since, None, None, 10.0))


def seen(entries: list[AuditEntry]) -> list[Seen]:
    return [(e.actor, e.act, e.outcome, e.verified) for e in entries]


def wait_for_entries(url: str, accounts: Accounts, n: int) -> list[AuditEntry]:
    """The trail once it holds at least `n` entries."""

    def enough() -> list[AuditEntry] | None:
        entries = audit(url, accounts)
        return entries if len(entries) >= n else None

    found = wait_for(enough, timeout=30, interval=0.2, what=f"{n} audit entries")
    assert found is not None
    return found


def test_each_roles_acts_are_recorded_with_its_account_and_a_restart_keeps_them(
    broker: tuple[str, bool], accounts: Accounts, tmp_path: Path
) -> None:
    url, vouched = broker
    db = tmp_path / "coordinator.sqlite3"
    with coordinator(url, accounts, db, vouched):
        with peer(url, accounts, "operator", "operator-peer") as op:
            reply = op.reply_to(op.send_control_unit("unit1", "pause").request_id)
            assert reply.reason == "unknown unit 'unit1'"
        with peer(url, accounts, "ann", "ann-peer") as ann:
            assert ann.set_goal("unit1", Cell(1, 1)).reason == "unknown unit 'unit1'"
        with peer(url, accounts, "dashboard", "dashboard-page-1") as page:
            assert page.reply_to(page.send_control_unit("unit1", "resume").request_id).reason
        with MqttProbe(login(url, accounts, "vera")) as viewer:
            # A viewer publishes nothing: the broker drops it, nothing reaches the coordinator.
            viewer.publish(T.fleet("estop"), b"engaged|vera|a viewer's stop", retain=True)
        with peer(url, accounts, "operator", "operator-peer") as op:
            op.engage("checking", by="operator-peer")
            wait_for_entries(url, accounts, 4)
            op.release("checked", by="operator-peer")
        entries = wait_for_entries(url, accounts, 5)
    assert seen(entries) == [
        ("operator", "pause", "refused", vouched),
        ("ann", "set_goal", "refused", vouched),
        ("dashboard", "resume", "refused", vouched),
        ("operator", "stop_engage", "accepted", vouched),
        ("operator", "stop_release", "accepted", vouched),
    ]
    assert [e.via for e in entries] == ["operator-peer", "ann-peer", "dashboard-page-1"] + [
        "operator-peer"
    ] * 2
    # A restart: the trail is still there, and the retained latch read again is no new act.
    with coordinator(url, accounts, db, vouched, fresh=False) as again:
        wait_for(lambda: again.service.core.stop.view.latch is not None, what="the latch replayed")
        with peer(url, accounts, "ann", "ann-peer2") as ann:
            ann.set_goal("unit1", None)
        after = wait_for_entries(url, accounts, 6)
    assert seen(after) == [*seen(entries), ("ann", "clear_goal", "refused", vouched)]


def forged_submit(sender: str) -> bytes:
    return encode(
        SubmitJob(
            header=header(sender),
            request_id="forged-1",
            pickup=Cell(0, 0),
            dropoff=Cell(3, 2),
            mass_kg=1.0,
        )
    )


def test_a_client_cannot_forge_the_actor(
    broker: tuple[str, bool], accounts: Accounts, tmp_path: Path
) -> None:
    url, vouched = broker
    with coordinator(url, accounts, tmp_path / "c.sqlite3", vouched):
        with peer(url, accounts, "ann", "ann-peer") as ann:
            ann.raw_request("submit_job", forged_submit("admin"))  # no such account
            ann.raw_request("submit_job", forged_submit("operator-x"))  # another account's id
            ann.set_goal("unit1", Cell(1, 1))  # her own, after them on the same connection
        entries = wait_for_entries(url, accounts, 1 if vouched else 3)
    if vouched:
        # The embedded broker drops a request naming an id its account does not own.
        assert seen(entries) == [("ann", "set_goal", "refused", True)]
    else:
        # Mosquitto cannot look into payloads: the claims arrive, and are recorded as claims
        # (in any order: a goal is answered ahead of new jobs waiting, coordinator/inbox.py).
        assert sorted((e.actor or "", e.act, e.verified) for e in entries) == [
            ("admin", "submit_job", False),
            ("ann", "set_goal", False),
            ("operator", "submit_job", False),
        ]


def will_of(url: str, accounts: Accounts, account: str, topic: str, payload: bytes) -> bool:
    """Connect as `account` with this last will, then lose the link so the will is due; whether
    the broker refused the CONNECT instead."""
    client = MqttProbe(login(url, accounts, account)).will(topic, payload, retain=False)
    try:
        client.connect(timeout=5)
    except AssertionError as exc:
        assert "Not authorized" in str(exc), exc
        return True
    client.drop()
    return False


def test_a_last_will_cannot_forge_the_actor(
    broker: tuple[str, bool], accounts: Accounts, tmp_path: Path
) -> None:
    # As found: ann's will naming `operator` was audited as `cancel_job actor operator verified
    # True`, and the same for the latch: amqtt sent wills past the checks a publish passes.
    url, vouched = broker
    cancel = encode(CancelJob(header=header("operator"), request_id="will-1", job_id="j1"))
    with coordinator(url, accounts, tmp_path / "c.sqlite3", vouched):
        refused = [
            will_of(url, accounts, "ann", T.request("cancel_job"), cancel),
            will_of(url, accounts, "ann", T.fleet("estop"), b"engaged|operator|a will's stop"),
        ]
        with peer(url, accounts, "ann", "ann-peer") as ann:
            ann.set_goal("unit1", Cell(1, 1))  # her own, after the wills
        entries = wait_for_entries(url, accounts, 1 if vouched else 3)
    assert [e for e in entries if e.verified and e.actor != "ann"] == []  # nothing forged vouched
    if vouched:
        # The embedded broker refuses such a CONNECT: the will never exists.
        assert refused == [True, True]
        assert seen(entries) == [("ann", "set_goal", "refused", True)]
    else:
        # Mosquitto cannot look into a will either: the claims arrive, recorded as claims.
        assert refused == [False, False]
        assert sorted((e.actor or "", e.act, e.verified) for e in entries) == [
            ("ann", "set_goal", False),
            ("operator", "cancel_job", False),
            ("operator", "stop_engage", False),
        ]


def test_a_last_will_cannot_speak_for_another_on_errors_or_ack_alert(
    broker: tuple[str, bool], accounts: Accounts
) -> None:
    # As found: a device's will on `errors` went out as `sender: coordinator`, and ann's will on
    # `requests/ack_alert` would have the alert acknowledged by `operator`.
    url, vouched = broker
    forged_report = ErrorReport(header=header("coordinator"), topic="x", reason="a forged will")
    own_report = ErrorReport(header=header("device-unit1"), topic="x", reason="its own will")
    ack = AckAlert(header=header("operator"), request_id="will-ack", alert_id="a-1")
    with MqttProbe(login(url, accounts, "operator")) as watcher:
        for topic in (T.fleet("errors"), T.request("ack_alert")):
            watcher.subscribe(topic)
        refused = [
            will_of(url, accounts, "device-unit1", T.fleet("errors"), encode(forged_report)),
            will_of(url, accounts, "ann", T.request("ack_alert"), encode(ack)),
        ]
        # The control: a will naming its own sender is heard (so a forged one had its chance).
        assert not will_of(url, accounts, "device-unit1", T.fleet("errors"), encode(own_report))
        watcher.wait(T.fleet("errors"), lambda m: b"its own will" in m.payload)
        if not vouched:  # Mosquitto: the claim arrives (protocol.md section 10 says so)
            watcher.wait(T.fleet("errors"), lambda m: b"a forged will" in m.payload)
            watcher.wait(T.request("ack_alert"))
        heard = [m.payload for ms in watcher.messages.values() for m in ms]
    forged = [p for p in heard if b"a forged will" in p or b"will-ack" in p]
    if vouched:
        assert refused == [True, True]
        assert forged == []
    else:
        assert refused == [False, False]
        assert len(forged) == 2


def test_a_viewer_can_neither_read_the_audit_nor_overhear_it(
    broker: tuple[str, bool], accounts: Accounts, tmp_path: Path
) -> None:
    url, vouched = broker
    with coordinator(url, accounts, tmp_path / "c.sqlite3", vouched):
        with peer(url, accounts, "ann", "ann-peer") as ann:
            ann.set_goal("unit1", Cell(1, 1))
        with MqttProbe(login(url, accounts, "vera")) as viewer:
            # Whatever it may subscribe to (a broker may refuse a filter it cannot fully read).
            for topic in (f"{T.prefix}/#", f"{T.prefix}/audit/#", T.request("set_goal")):
                viewer.subscribe(topic)
            assert len(audit(url, accounts, "ann")) == 1  # ann's page went out meanwhile
            # After ann's page, ann sends something the viewer may read: by then her page would
            # have reached the viewer too, were it allowed to.
            with peer(url, accounts, "ann", "ann-peer") as ann:
                ann.set_goal("unit1", None)
            viewer.wait(T.request("set_goal"))
            assert not [t for t in viewer.messages if t.startswith(f"{T.prefix}/audit/")]


def test_the_dashboards_logins_logouts_and_failed_logins_are_recorded(
    broker: tuple[str, bool], accounts: Accounts, tmp_path: Path
) -> None:
    url, vouched = broker
    settings = DashboardSettings(
        broker_ws="ws://127.0.0.1:9", root=ROOT, accounts=accounts, audit_broker=url
    )
    app = create_app(settings)
    reporter = app.extensions["gridfleet_audit"]
    assert isinstance(reporter, LoginReporter)
    try:
        with coordinator(url, accounts, tmp_path / "c.sqlite3", vouched):
            web = app.test_client()
            ann = accounts.get("ann")
            bad = web.post("/api/login", json={"username": "ann", "password": "not hers at all"})
            assert bad.status_code == 401
            good = web.post("/api/login", json={"username": "ann", "password": ann.password})
            assert good.status_code == 200
            assert web.post("/api/logout", json={}).status_code == 200
            entries = wait_for_entries(url, accounts, 3)
    finally:
        reporter.stop()
    assert [(e.actor, e.act, e.outcome, e.verified, e.via) for e in entries] == [
        ("ann", "login_failed", "refused", False, "dashboard"),
        ("ann", "login", "accepted", vouched, "dashboard"),
        ("ann", "logout", "accepted", vouched, "dashboard"),
    ]
    assert entries[0].reason == "wrong user name or password"
    assert entries[1].detail == "from 127.0.0.1"


def test_the_command_line_prints_the_trail_and_refuses_a_bad_range(
    broker: tuple[str, bool], accounts: Accounts, tmp_path: Path
) -> None:
    url, vouched = broker
    file = tmp_path / "accounts.toml"
    write_accounts(accounts, file)
    common = ["--broker", url, "--accounts", str(file), "--root", ROOT]
    with coordinator(url, accounts, tmp_path / "c.sqlite3", vouched):
        with peer(url, accounts, "ann", "ann-peer") as ann:
            ann.set_goal("unit1", Cell(1, 1))
        done = gridfleet("audit", *common, "--since", "1h", "--csv", "--actor", "ann")
        assert done.returncode == 0, done.stderr
        rows = list(csv.reader(io.StringIO(done.stdout)))
        assert rows[0] == [
            "at",
            "actor",
            "verified",
            "via",
            "act",
            "target",
            "detail",
            "outcome",
            "reason",
        ]
        assert [row[1:] for row in rows[1:]] == [
            [
                "ann",
                str(vouched),
                "ann-peer",
                "set_goal",
                "unit1",
                "to [1, 1]",
                "refused",
                "unknown unit 'unit1'",
            ]
        ]
        viewer = ["--account", "vera", "--since", "1h", "--timeout", "2"]
        as_viewer = gridfleet("audit", *common, *viewer)
        assert as_viewer.returncode == 2
        assert "no reply from the coordinator to audit " in as_viewer.stderr
        assert "may this account read the audit?" in as_viewer.stderr
    backwards = gridfleet("audit", "--since", "2026-11-26T14:00", "--until", "2026-11-26T13:00")
    assert backwards.returncode == 2
    assert backwards.stderr.splitlines() == [
        "gridfleet audit: error: --since 2026-11-26T14:00:00+00:00 is after --until "
        "2026-11-26T13:00:00+00:00: nothing can lie between"
    ]
