"""The alerts core, pure: messages and times in, exactly the alerts, views, replies and notices out."""

from __future__ import annotations

import json
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from gridfleet.alerts.core import AlertsCore, Effects
from gridfleet.alerts.settings import AlertSettings, load_settings, with_flag
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import (
    Connection,
    CoordinatorStatus,
    HeaderStamper,
    JobsView,
    JobView,
    Leds,
    Reply,
    Sensors,
    Topics,
    UnitState,
    decode,
    encode,
)
from gridfleet.protocol.messages import AckAlert, AlertEntry, AlertsView, ErrorReport

T = Topics("site")
T0 = datetime(2026, 11, 21, 10, 0, tzinfo=UTC)
SETTINGS = AlertSettings(
    unit_lost_s=30.0,
    unit_stuck_s=60.0,
    job_queued_s=600.0,
    step_rate_below=0.5,
    coordinator_down_s=None,  # on in the coordinator's own tests: the others run for minutes
    broker_down_s=10.0,
)
WATCHING_COORDINATOR = replace(SETTINGS, coordinator_down_s=15.0)
ACCOUNTS = {"operator": "operator", "ann": "viewer", "unit1": "unit", "dashboard": "dashboard"}


class Clock:
    """The wall clock the core stamps with: T0 plus the seconds a test sets."""

    def __init__(self) -> None:
        self.s = 0.0

    def __call__(self) -> datetime:
        return T0 + timedelta(seconds=self.s)


def at(s: float) -> datetime:
    return T0 + timedelta(seconds=s)


class Rig:
    """A core with a coordinator online and the broker connected at t=0, and its clock."""

    def __init__(
        self, settings: AlertSettings = SETTINGS, *, retained: bool = True, **kw: Any
    ) -> None:
        self.clock = Clock()
        self.core = AlertsCore(
            T, settings, HeaderStamper("alerts", self.clock), nonce="n1", now=0.0, **kw
        )
        self.connected = self.core.connected(0.0)
        if retained:  # the view a last run left, with nothing in force: read, ours goes out
            empty = AlertsView(header=HeaderStamper("alerts")("alerts"), active=[])
            self.connected = self.send(0.0, T.fleet("alerts"), encode(empty))
        self.send(0.0, T.fleet("coordinator"), status("online"))

    def send(self, s: float, topic: str, payload: bytes) -> Effects:
        self.clock.s = s
        return self.core.on_message(topic, payload, s)

    def tick(self, s: float) -> Effects:
        self.clock.s = s
        return self.core.tick(s)

    def state(
        self, s: float, unit: str, square: tuple[int, int], status: str = "moving"
    ) -> Effects:
        return self.send(s, T.unit("state", unit), unit_state(unit, square, status))

    def ack(self, s: float, alert_id: str, sender: str = "operator-cli-1", **kw: Any) -> Effects:
        request = AckAlert(
            header=HeaderStamper(sender)("ack_alert"),
            request_id="r-1",
            reply_to=sender,
            alert_id=alert_id,
            **kw,
        )
        return self.send(s, T.request("ack_alert"), encode(request))


def unit_state(unit: str, square: tuple[int, int], status: str = "moving") -> bytes:
    free = Sensors(N="free", E="free", S="free", W="free")
    reason = "released square [5, 1] is taken by unit2" if status == "waiting" else None
    state = UnitState(
        header=HeaderStamper(unit)("state"),
        step=1,
        position=Cell(*square),
        direction="-",
        status=status,  # type: ignore[arg-type]
        wait_reason=reason,
        leds=Leds(),
        sensors=free,
    )
    return encode(state)


def connection(unit: str, state: str) -> bytes:
    return encode(Connection(header=HeaderStamper(unit)("connection"), state=state))  # type: ignore[arg-type]


def status(state: str, achieved: float | None = None, period: float = 0.1) -> bytes:
    return encode(
        CoordinatorStatus(
            header=HeaderStamper("coordinator")("coordinator"),
            state=state,  # type: ignore[arg-type]
            step_period_s=period,
            achieved_step_s=achieved,
        )
    )


def jobs(*queued: str, assigned: tuple[str, ...] = ()) -> bytes:
    def job(ident: str, state: str) -> JobView:
        wait = "no_unit_free" if state == "queued" else None
        why = "every unit that can carry 1.0 kg is busy (unit2)" if wait else None
        return JobView(
            id=ident,
            pickup=Cell(1, 1),
            dropoff=Cell(2, 2),
            mass_kg=1.0,
            state=state,  # type: ignore[arg-type]
            unit="unit2" if state != "queued" else None,
            wait=wait,  # type: ignore[arg-type]
            wait_reason=why,
        )

    listed = [job(j, "queued") for j in queued] + [job(j, "assigned") for j in assigned]
    return encode(JobsView(header=HeaderStamper("coordinator")("jobs"), jobs=listed))


def views(effects: Effects) -> list[AlertsView]:
    return [
        decode(AlertsView, o.payload, 8 << 20)
        for o in effects.publish
        if o.topic.endswith("/alerts")
    ]


def summary(view: AlertsView) -> tuple[list[tuple[Any, ...]], list[tuple[Any, ...]]]:
    """(active, cleared) as (id, rule, subject, severity, raised, cleared, acked by)."""

    def row(a: Any) -> tuple[Any, ...]:
        return (a.id, a.rule, a.subject, a.severity, a.raised_at, a.cleared_at, a.acked_by)

    return [row(a) for a in view.active], [row(a) for a in view.cleared]


def notices(effects: Effects) -> list[tuple[str, str, str]]:
    """(event, alert id, text line) of each webhook notice."""
    out = []
    for body in effects.notices:
        data = json.loads(body)
        assert data["fleet"] == "site"
        out.append((data["event"], data["alert"]["id"], data["text"]))
    return out


def replies(effects: Effects) -> list[tuple[str, bool, str | None]]:
    return [
        (o.topic, r.accepted, r.reason)
        for o in effects.publish
        if "/replies/" in o.topic
        for r in [decode(Reply, o.payload)]
    ]


def errors(effects: Effects) -> list[str]:
    return [
        decode(ErrorReport, o.payload).reason
        for o in effects.publish
        if o.topic.endswith("/errors")
    ]


# ---- raising and clearing -------------------------------------------------------------------


def test_a_unit_silent_longer_than_its_threshold_raises_and_clears_when_heard_again() -> None:
    rig = Rig()
    assert views(rig.connected) == [AlertsView(header=views(rig.connected)[0].header, active=[])]
    rig.send(1.0, T.unit("connection", "unit1"), connection("unit1", "online"))
    assert views(rig.state(2.0, "unit1", (3, 4))) == []  # nothing changed: no view
    assert rig.tick(32.0).notices == []  # 30 s of silence: not yet longer than 30 s
    raised = rig.tick(32.5)
    assert notices(raised) == [
        ("raised", "n1-1", "[CRITICAL] unit unit1 lost: no state, nothing heard for 30 s")
    ]
    (view,) = views(raised)
    assert summary(view) == ([("n1-1", "unit_lost", "unit1", "critical", at(32.5), None, None)], [])
    assert rig.tick(40.0) == Effects()  # raised once, not again
    cleared = rig.state(41.0, "unit1", (3, 4))
    assert notices(cleared) == [
        ("cleared", "n1-1", "[CLEARED] unit unit1 lost: no state, nothing heard for 30 s")
    ]
    (view,) = views(cleared)
    assert summary(view) == (
        [],
        [("n1-1", "unit_lost", "unit1", "critical", at(32.5), at(41.0), None)],
    )
    assert rig.core.raised_total["unit_lost"] == rig.core.cleared_total["unit_lost"] == 1


def test_a_lost_unit_removed_for_good_clears_its_alert_without_an_error() -> None:
    # The coordinator clears a removed unit's retained topics (protocol.md §6.11): an empty
    # state and connection say it is gone, not a malformed message.
    rig = Rig()
    rig.send(1.0, T.unit("connection", "unit1"), connection("unit1", "online"))
    rig.state(2.0, "unit1", (3, 4))
    assert notices(rig.tick(32.5))[0][0] == "raised"
    cleared = rig.send(33.0, T.unit("state", "unit1"), b"")
    assert notices(cleared) == [
        ("cleared", "n1-1", "[CLEARED] unit unit1 lost: no state, nothing heard for 30 s")
    ]
    assert [out.topic for out in cleared.publish] == [T.fleet("alerts")]  # no error report
    assert rig.send(33.0, T.unit("connection", "unit1"), b"").publish == []
    assert rig.tick(100.0) == Effects()  # gone: nothing is raised for it again


def test_a_broken_connection_is_named_and_a_clean_goodbye_raises_nothing() -> None:
    rig = Rig()
    rig.state(0.0, "unit1", (0, 0))
    rig.state(0.0, "unit2", (1, 0))
    rig.send(5.0, T.unit("connection", "unit1"), connection("unit1", "broken"))
    rig.send(5.0, T.unit("connection", "unit2"), connection("unit2", "offline"))
    assert notices(rig.tick(31.0)) == [
        (
            "raised",
            "n1-1",
            "[CRITICAL] unit unit1 lost: its connection broke, nothing heard for 31 s",
        )
    ]
    assert rig.tick(100.0) == Effects()  # unit2 said offline: nobody is paged for it


def test_a_unit_waiting_on_one_square_is_stuck_and_moving_clears_it() -> None:
    rig = Rig()
    rig.state(0.0, "unit1", (2, 2), "waiting")
    rig.state(20.0, "unit1", (2, 2), "waiting")  # heard, still on the same square
    rig.state(50.0, "unit1", (2, 2), "holding")  # still not getting on
    effects = rig.state(60.5, "unit1", (2, 2), "waiting")
    assert notices(effects) == [
        (
            "raised",
            "n1-1",
            "[WARNING] unit unit1 waiting on [2, 2] for 60 s: "
            "released square [5, 1] is taken by unit2",
        )
    ]
    assert views(effects)[0].active[0].rule == "unit_stuck"
    assert notices(rig.state(61.0, "unit1", (3, 2), "waiting")) == [
        (
            "cleared",
            "n1-1",
            "[CLEARED] unit unit1 waiting on [2, 2] for 60 s: "
            "released square [5, 1] is taken by unit2",
        )
    ]
    # Waiting on the new square starts the count again.
    assert rig.state(100.0, "unit1", (3, 2), "waiting").notices == []


def test_a_job_queued_too_long_raises_and_clears_once_assigned() -> None:
    rig = Rig()
    rig.send(0.0, T.fleet("jobs"), jobs("job-7"))
    rig.send(300.0, T.fleet("jobs"), jobs("job-7", "job-8"))
    raised = rig.tick(600.5)
    assert notices(raised) == [
        (
            "raised",
            "n1-1",
            "[WARNING] job job-7 queued for 10.0 min: every unit that can carry 1.0 kg is busy "
            "(unit2)",
        )
    ]
    cleared = rig.send(700.0, T.fleet("jobs"), jobs("job-8", assigned=("job-7",)))
    assert [n[0:2] for n in notices(cleared)] == [("cleared", "n1-1")]
    assert [n[0:2] for n in notices(rig.tick(900.5))] == [("raised", "n1-2")]  # job-8 since 300


def test_the_stop_raises_at_once_and_clears_on_release() -> None:
    rig = Rig()
    engaged = rig.send(3.0, T.fleet("estop"), b"engaged|operator|aisle 3 blocked")
    assert notices(engaged) == [
        ("raised", "n1-1", "[CRITICAL] emergency stop engaged by operator: aisle 3 blocked")
    ]
    assert notices(rig.send(9.0, T.fleet("estop"), b"released|operator|")) == [
        ("cleared", "n1-1", "[CLEARED] emergency stop engaged by operator: aisle 3 blocked")
    ]
    # A unit's own press holds the fleet as well.
    assert notices(rig.send(10.0, T.unit("stop", "unit2"), b"engaged|unit2|bumper hit")) == [
        ("raised", "n1-2", "[CRITICAL] emergency stop engaged by unit2: bumper hit")
    ]


def test_a_slow_fleet_raises_step_rate_low_and_recovers() -> None:
    rig = Rig()
    assert rig.send(5.0, T.fleet("coordinator"), status("online", achieved=0.15)).notices == []
    assert notices(rig.send(10.0, T.fleet("coordinator"), status("online", achieved=0.25))) == [
        ("raised", "n1-1", "[WARNING] the fleet steps 4.00 times a second, 40 % of its 10.00")
    ]
    cleared = rig.send(15.0, T.fleet("coordinator"), status("online", achieved=0.12))
    assert [n[0] for n in notices(cleared)] == ["cleared"]


def test_the_coordinator_down_or_silent_raises_after_its_threshold() -> None:
    rig = Rig(WATCHING_COORDINATOR)
    rig.send(1.0, T.fleet("coordinator"), status("broken"))
    assert rig.tick(16.0).notices == []
    assert notices(rig.tick(16.5)) == [
        ("raised", "n1-1", "[CRITICAL] coordinator down: its status says broken for 16 s")
    ]
    assert [n[0] for n in notices(rig.send(20.0, T.fleet("coordinator"), status("online")))] == [
        "cleared"
    ]
    assert notices(rig.tick(35.5)) == [("raised", "n1-2", "[CRITICAL] coordinator silent for 16 s")]


def test_no_coordinator_at_all_counts_as_down_from_the_start() -> None:
    clock = Clock()
    core = AlertsCore(T, WATCHING_COORDINATOR, HeaderStamper("alerts", clock), nonce="n1", now=0.0)
    core.connected(0.0)
    assert notices(core.tick(15.5)) == [
        ("raised", "n1-1", "[CRITICAL] coordinator down: no status for 16 s")
    ]


def test_the_brokers_loss_raises_by_webhook_alone_and_judges_nothing_else_meanwhile() -> None:
    rig = Rig()
    rig.state(0.0, "unit1", (0, 0))
    lost = rig.core.disconnected(5.0)
    assert lost == Effects()
    raised = rig.tick(15.5)
    assert notices(raised) == [
        ("raised", "n1-1", "[CRITICAL] the alerts process has had no broker for 10 s")
    ]
    assert raised.publish == []  # no session to publish on
    # Deaf for 60 s, it raises nothing about the units or the coordinator it could not hear.
    assert rig.tick(60.0) == Effects()
    back = rig.core.connected(61.0)
    assert [n[0:2] for n in notices(back)] == [("cleared", "n1-1")]
    (view,) = views(back)
    assert view.active == [] and [a.rule for a in view.cleared] == ["broker_down"]
    # The units' silence counts from the reconnection.
    assert rig.tick(91.0).notices == []
    assert [n[0:2] for n in notices(rig.tick(91.5))] == [("raised", "n1-2")]


def test_rules_switched_off_raise_nothing() -> None:
    off = AlertSettings(
        unit_lost_s=None,
        unit_stuck_s=None,
        job_queued_s=None,
        estop=False,
        step_rate_below=None,
        coordinator_down_s=None,
        broker_down_s=None,
    )
    rig = Rig(off)
    rig.state(0.0, "unit1", (0, 0), "waiting")
    rig.send(0.0, T.fleet("jobs"), jobs("job-1"))
    rig.send(0.0, T.fleet("estop"), b"engaged|operator|")
    rig.send(0.0, T.fleet("coordinator"), status("broken", achieved=1.0))
    rig.core.disconnected(1.0)
    rig.core.connected(5000.0)
    assert rig.tick(10000.0) == Effects()
    assert rig.core.active == {}


def test_a_bad_message_is_reported_and_changes_nothing() -> None:
    rig = Rig()
    rig.state(0.0, "unit1", (0, 0))
    effects = rig.send(1.0, T.unit("state", "unit1"), b'{"header": 1}')
    assert errors(effects) == [
        "UnitState: field 'header': Input should be an object (and 6 more problems)"
    ]
    assert views(effects) == [] and effects.notices == []
    # Nor was it a sign of life: the silence counts from the last good state.
    assert [n[0] for n in notices(rig.tick(30.5))] == ["raised"]
    assert rig.send(2.0, "elsewhere/topic", b"x") == Effects()


# ---- acknowledgements -----------------------------------------------------------------------


def lost_unit(rig: Rig) -> None:
    rig.state(0.0, "unit1", (0, 0))
    rig.tick(31.0)


def test_an_operator_acknowledges_as_their_account_and_it_shows_until_cleared() -> None:
    rig = Rig(accounts=ACCOUNTS)
    lost_unit(rig)
    acked = rig.ack(40.0, "n1-1", sender="operator-cli-9c1e")
    assert replies(acked) == [(T.reply("operator-cli-9c1e"), True, None)]
    assert notices(acked) == [
        (
            "acknowledged",
            "n1-1",
            "[ACKNOWLEDGED by operator] unit unit1 lost: no state, nothing heard for 31 s",
        )
    ]
    (view,) = views(acked)
    # The account, not the client id the request came from.
    assert summary(view)[0] == [
        ("n1-1", "unit_lost", "unit1", "critical", at(31.0), None, "operator")
    ]
    assert view.active[0].acked_at == at(40.0)
    # Again (a retry, or a second person): accepted, and the first acknowledgement stands.
    again = rig.ack(41.0, "n1-1", sender="dashboard")
    assert replies(again) == [(T.reply("dashboard"), True, None)]
    assert views(again) == [] and again.notices == []
    cleared = rig.state(50.0, "unit1", (0, 0))
    assert summary(views(cleared)[0])[1][0][-1] == "operator"  # cleared, still acknowledged


def test_a_cleared_alert_can_still_be_acknowledged() -> None:
    rig = Rig(accounts=ACCOUNTS)
    lost_unit(rig)
    rig.state(35.0, "unit1", (0, 0))
    acked = rig.ack(40.0, "n1-1")
    assert replies(acked) == [(T.reply("operator-cli-1"), True, None)]
    assert [a.acked_by for a in views(acked)[0].cleared] == ["operator"]


@pytest.mark.parametrize(
    ("sender", "alert_id", "reason"),
    [
        (
            "operator-cli-1",
            "n1-9",
            "no alert 'n1-9': it is neither active nor among the latest cleared",
        ),
        ("ann", "n1-1", "account 'ann' (viewer) may not acknowledge alerts"),
        ("ann-laptop", "n1-1", "account 'ann' (viewer) may not acknowledge alerts"),
        ("unit1", "n1-1", "account 'unit1' (unit) may not acknowledge alerts"),
        ("stranger", "n1-1", "sender 'stranger' belongs to no account"),
    ],
)
def test_a_refused_acknowledgement_says_why_in_one_line_and_changes_nothing(
    sender: str, alert_id: str, reason: str
) -> None:
    rig = Rig(accounts=ACCOUNTS)
    lost_unit(rig)
    before = rig.core.view().payload
    refused = rig.ack(40.0, alert_id, sender=sender)
    assert replies(refused) == [(T.reply(sender), False, reason)]
    assert errors(refused) == [reason]
    assert views(refused) == [] and refused.notices == []
    assert json.loads(rig.core.view().payload)["active"] == json.loads(before)["active"]


def test_a_malformed_acknowledgement_is_refused_with_a_reply_when_it_can_be_addressed() -> None:
    rig = Rig(accounts=ACCOUNTS)
    lost_unit(rig)
    topic = T.request("ack_alert")
    unreadable = rig.send(40.0, topic, b"{not json")
    assert replies(unreadable) == []
    assert errors(unreadable) == [
        "AckAlert: malformed JSON (Invalid JSON: key must be a string at line 1 column 2)"
    ]
    header = {"version": "1.6", "seq": 0, "timestamp": "2026-11-21T10:00:00Z", "sender": "operator"}
    no_id = {"header": header, "request_id": "r-2", "reply_to": "operator"}
    refused = rig.send(41.0, topic, json.dumps(no_id).encode())
    assert replies(refused) == [
        (T.reply("operator"), False, "AckAlert: field 'alert_id': Field required")
    ]
    assert rig.core.active[("unit_lost", "unit1")].acked_by is None


def test_without_accounts_the_sender_is_taken_as_it_is() -> None:
    rig = Rig()
    lost_unit(rig)
    acked = rig.ack(40.0, "n1-1", sender="dashboard")
    assert views(acked)[0].active[0].acked_by == "dashboard"


def test_the_webhook_body_carries_the_alert_whole() -> None:
    rig = Rig()
    rig.state(0.0, "unit1", (0, 0))
    (raised,) = rig.tick(31.0).notices
    assert json.loads(raised) == {
        "event": "raised",
        "at": "2026-11-21T10:00:31Z",
        "fleet": "site",
        "text": "[CRITICAL] unit unit1 lost: no state, nothing heard for 31 s",
        "alert": {
            "id": "n1-1",
            "rule": "unit_lost",
            "subject": "unit1",
            "severity": "critical",
            "text": "unit unit1 lost: no state, nothing heard for 31 s",
            "raised_at": "2026-11-21T10:00:31Z",
            "cleared_at": None,
            "acked_by": None,
            "acked_at": None,
        },
    }


def test_chat_markup_and_control_characters_in_a_reason_are_neutralised_in_the_webhook_text() -> (
    None
):
    rig = Rig()
    hostile = "<!channel> see <http://evil.example|the manual> & \x1b[2Jbye\x07\u202e"
    raised = rig.send(3.0, T.fleet("estop"), f"engaged|operator|{hostile}".encode())
    (body,) = raised.notices
    data = json.loads(body)
    assert data["text"] == (
        "[CRITICAL] emergency stop engaged by operator: &lt;!channel&gt; see "
        "&lt;http://evil.example|the manual&gt; &amp; [2Jbye"
    )
    # The structured fields stay as the fleet said them: a receiver that builds its own text
    # from them, and the view fleet/alerts, get the reason whole.
    assert data["alert"]["text"] == f"emergency stop engaged by operator: {hostile}"
    assert views(raised)[0].active[0].text == data["alert"]["text"]
    # A unit's wait_reason goes the same way; the line is bounded, cut on a whole entity.
    reason = "\r\n[CLEARED] " + "<" * 488
    long = UnitState.model_validate(
        {**json.loads(unit_state("unit1", (2, 2), "waiting")), "wait_reason": reason}
    )
    rig.send(4.0, T.unit("state", "unit1"), encode(long))
    (stuck,) = rig.send(65.0, T.unit("state", "unit1"), encode(long)).notices
    text = json.loads(stuck)["text"]
    assert text.startswith("[WARNING] unit unit1 waiting on [2, 2] for 61 s: [CLEARED] &lt;&lt;")
    assert len(text) <= 400 and text.endswith("&lt;…")
    # The alert's own text keeps the reason as said, as much of it as MAX_TEXT holds.
    whole = json.loads(stuck)["alert"]["text"]
    assert "<" not in text and len(whole) == 500
    assert whole.startswith("unit unit1 waiting on [2, 2] for 61 s: \r\n[CLEARED] <<")
    assert whole.endswith("<<…")


# ---- settings ---------------------------------------------------------------------------------


def test_settings_come_from_the_file_then_the_flags(tmp_path: Path) -> None:
    config = tmp_path / "alerts.toml"
    config.write_text(
        '[alerts]\nunit_lost_s = 12\nunit_stuck_s = false\nestop = false\nwebhook = "http://h:8/x"\n'
        'webhook_queue = "q.sqlite3"\n',
        encoding="utf-8",
    )
    settings = load_settings(config)
    assert (settings.unit_lost_s, settings.unit_stuck_s, settings.estop) == (12.0, None, False)
    assert settings.webhook == "http://h:8/x" and settings.webhook_queue == str(
        tmp_path / "q.sqlite3"
    )
    settings = with_flag(with_flag(settings, "unit_stuck_s=90"), "job_queued_s=off")
    assert (settings.unit_stuck_s, settings.job_queued_s) == (90.0, None)


@pytest.mark.parametrize(
    ("flag", "message"),
    [
        (
            "unit_lost",
            "--rule 'unit_lost': give NAME=VALUE, e.g. unit_lost_s=30 or unit_stuck_s=off",
        ),
        ("unit_lots_s=3", "--rule unit_lots_s=3: unknown alert setting 'unit_lots_s' (known: "),
        (
            "unit_lost_s=-1",
            "--rule unit_lost_s=-1: unit_lost_s -1.0: give a number of seconds > 0, or off",
        ),
        (
            "unit_lost_s=soon",
            "--rule unit_lost_s=soon: unit_lost_s 'soon' is not a number (or off)",
        ),
        (
            "unit_lost_s=nan",
            "--rule unit_lost_s=nan: unit_lost_s nan: give a number of seconds > 0, or off",
        ),
        (
            "step_rate_below=2",
            "--rule step_rate_below=2: step_rate_below 2.0: give a share of the ",
        ),
        (
            "coordinator_down_s=3",
            "--rule coordinator_down_s=3: coordinator_down_s 3: give at least 10 s",
        ),
        ("estop=maybe", "--rule estop=maybe: estop is true or false"),
        ("webhook=ftp://h/x", "--rule webhook=ftp://h/x: webhook: ftp scheme or no host"),
    ],
)
def test_a_bad_setting_is_one_line_naming_it(flag: str, message: str) -> None:
    with pytest.raises(ConfigError) as refused:
        with_flag(AlertSettings(), flag)
    assert str(refused.value).startswith(message) and "\n" not in str(refused.value)


def test_a_bad_config_file_names_the_file(tmp_path: Path) -> None:
    config = tmp_path / "alerts.toml"
    config.write_text("[alerts]\nunit_lost_s = true\n", encoding="utf-8")
    with pytest.raises(
        ConfigError, match=rf"^{config}: unit_lost_s is a number, or false \(off\)$"
    ):
        load_settings(config)
    config.write_text("alerts = 3\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"\[alerts\] must be a table"):
        load_settings(config)


# ---- a restart -------------------------------------------------------------------------------


def last_runs_view() -> bytes:
    """What a stopped alerts process left retained: unit1 lost (acknowledged), unit2 lost."""

    def lost(n: int, unit: str, acked: str | None) -> AlertEntry:
        return AlertEntry(
            id=f"old-{n}",
            rule="unit_lost",
            subject=unit,
            severity="critical",
            text=f"unit {unit} lost: its connection broke, nothing heard for 31 s",
            raised_at=at(-100),
            acked_by=acked,
            acked_at=at(-90) if acked else None,
        )

    gone = lost(0, "unit3", None).model_copy(update={"cleared_at": at(-95)})
    view = AlertsView(
        header=HeaderStamper("alerts")("alerts"),
        active=[lost(1, "unit1", "operator"), lost(2, "unit2", None)],
        cleared=[gone],
    )
    return encode(view)


def test_a_restarted_alerts_process_takes_over_what_still_holds_and_clears_what_does_not() -> None:
    # As found: a restart raised every alert still in force again under a new id, and the
    # people on call were paged twice for one lost unit.
    rig = Rig(retained=False)
    rig.send(0.1, T.unit("connection", "unit1"), connection("unit1", "broken"))  # retained
    rig.state(0.1, "unit2", (1, 1))
    rig.send(0.1, T.unit("connection", "unit2"), connection("unit2", "online"))
    taken = rig.send(0.2, T.fleet("alerts"), last_runs_view())
    assert notices(taken) == []  # nothing raised, nothing cleared yet
    (view,) = views(taken)
    assert [(a.id, a.acked_by) for a in view.active] == [("old-1", "operator"), ("old-2", None)]
    assert [a.id for a in view.cleared] == ["old-0"]
    # unit2 keeps sending states: it is back, and its alert clears after the threshold's wait.
    for s in range(1, 40):
        rig.state(float(s), "unit2", (1, 1))
    assert notices(rig.tick(40.0)) == []  # unit1 found lost again (31 s silent): taken over
    cleared = rig.tick(40.5)  # past 30 s + 10 s: unit2's was not found again
    assert notices(cleared) == [
        (
            "cleared",
            "old-2",
            "[CLEARED] unit unit2 lost: its connection broke, nothing heard for 31 s",
        )
    ]
    (view,) = views(cleared)
    assert [(a.id, a.acked_by) for a in view.active] == [("old-1", "operator")]
    for s in range(41, 100):
        assert rig.state(float(s), "unit2", (1, 1)) == Effects()
    assert rig.tick(100.0) == Effects()  # unit1's stays, raised once, by the last run
    assert rig.core.raised_total["unit_lost"] == 0
    # The view this run publishes, coming back, is not taken over again.
    assert rig.send(100.5, T.fleet("alerts"), encode(view)) == Effects()


def test_with_no_view_retained_the_first_goes_out_after_the_wait_and_is_not_taken_over() -> None:
    rig = Rig(retained=False)
    assert views(rig.connected) == []  # not yet: it would replace a retained view still coming
    assert views(rig.tick(1.9)) == []
    (own,) = views(rig.tick(2.0))  # INHERIT_WAIT_S: there was none
    assert own.active == []
    rig.send(30.0, T.unit("connection", "unit1"), connection("unit1", "broken"))
    (raised,) = views(rig.tick(61.0))
    assert [a.id for a in raised.active] == ["n1-1"]
    assert rig.send(61.5, T.fleet("alerts"), encode(raised)) == Effects()  # ours, come back
    assert rig.send(62.0, T.fleet("alerts"), last_runs_view()) == Effects()  # too late
    assert list(rig.core.active) == [("unit_lost", "unit1")]


def test_the_coordinator_leaves_acknowledgements_to_the_alerts_process() -> None:
    from gridfleet.coordinator import inbound

    request = AckAlert(
        header=HeaderStamper("operator")("ack_alert"),
        request_id="r-1",
        reply_to="operator",
        alert_id="n1-1",
    )
    # Not refused, not answered: a reply of its own would race the alerts process's.
    assert inbound.read(T, T.request("ack_alert"), encode(request)) is None
    assert inbound.reply_address(T, T.request("ack_alert"), encode(request)) == (None, None)


def test_an_unreadable_retained_view_is_reported_and_the_good_one_after_it_is_still_taken_over() -> (
    None
):
    rig = Rig(retained=False)
    bad = rig.send(0.1, T.fleet("alerts"), b'{"header": {"version": "1.6"}, "active": 7}')
    (error,) = errors(bad)
    assert error.startswith("AlertsView: ") and views(bad) == [] and bad.notices == []
    assert not rig.core.settled and rig.core.active == {}  # still waiting for a view to read
    (view,) = views(rig.send(0.2, T.fleet("alerts"), last_runs_view()))
    assert [a.id for a in view.active] == ["old-1", "old-2"]


def failure_report(sender: str, topic: str, reason: str) -> bytes:
    header = HeaderStamper(sender)("errors")
    return encode(ErrorReport(header=header, topic=topic, reason=reason))


def test_a_components_failed_handler_raises_handler_failures_until_a_quiet_window() -> None:
    from gridfleet.failures import failure_reason

    rig = Rig(replace(SETTINGS, handler_failures_s=60.0))
    state = "uagv/v2/acme/sn-7/state"
    # A refusal on `errors` is no failure of anybody's; junk there is dropped unanswered.
    refusal = failure_report("coordinator", T.request("submit_job"), "SubmitJob: malformed JSON")
    assert rig.send(1.0, T.fleet("errors"), refusal).notices == []
    assert rig.send(1.5, T.fleet("errors"), b"not json") == Effects()
    raised = rig.send(
        2.0,
        T.fleet("errors"),
        failure_report("agv1", state, failure_reason("vda5050", "TypeError")),
    )
    assert notices(raised) == [
        (
            "raised",
            "n1-1",
            f"[WARNING] vda5050 failed handling a message on {state} (TypeError); its log has "
            "the details",
        )
    ]
    (alert,) = rig.core.active.values()
    assert (alert.rule, alert.subject, alert.severity) == ("handler_failures", "vda5050", "warning")
    many = failure_reason("vda5050", "TypeError", 12)
    assert rig.send(50.0, T.fleet("errors"), failure_report("agv1", state, many)).notices == []
    assert rig.tick(110.0).notices == []  # 60 s after the latest: still within the window
    assert [n[0] for n in notices(rig.tick(110.5))] == ["cleared"]
    # Off: never raised.
    off = Rig(replace(SETTINGS, handler_failures_s=None))
    again = failure_report("unit1", T.unit("order", "unit1"), failure_reason("unit", "KeyError"))
    assert off.send(1.0, T.fleet("errors"), again).notices == []
    assert (T.fleet("errors"), 1) in rig.core.subscriptions()
