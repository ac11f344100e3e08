"""The alerts process on a real broker: a lost unit is raised, reaches a webhook, is acknowledged
by a person's account and clears; a receiver that is down gets it later; `/metrics` counts it."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import threading
import urllib.request
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest

from gridfleet.accounts import Account, Accounts, default_accounts, new_password
from gridfleet.alerts.settings import AlertSettings
from gridfleet.alerts.shell import AlertsShell
from gridfleet.alerts.webhook import Backoff
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.grid import Cell
from gridfleet.metrics import MetricsOptions
from gridfleet.ports import free_port
from gridfleet.protocol import (
    Connection,
    HeaderStamper,
    Leds,
    Reply,
    Sensors,
    Topics,
    UnitState,
    decode,
    encode,
)
from gridfleet.protocol.messages import AckAlert, AlertsView
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.cli import gridfleet
from support.mosquitto import mosquitto_with_accounts
from support.probe import MqttProbe
from support.security import login
from support.wait import wait_for

pytestmark = pytest.mark.slow  # seconds a test: in make test, not in test-fast

# Only the rules a test drives: the others (the coordinator's absence above all) stay quiet.
QUIET = AlertSettings(
    unit_lost_s=0.5,
    unit_stuck_s=None,
    job_queued_s=None,
    step_rate_below=None,
    coordinator_down_s=None,
    broker_down_s=None,
)
FAST = Backoff(first=0.05, most=0.2)


class Receiver:
    """A webhook receiver on loopback: keeps every JSON body POSTed to it, answers 204."""

    def __init__(self, port: int = 0) -> None:
        self.bodies: list[dict[str, Any]] = []
        bodies = self.bodies

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                length = int(self.headers["Content-Length"])
                assert self.headers["Content-Type"] == "application/json"
                bodies.append(json.loads(self.rfile.read(length)))
                self.send_response(204)
                self.end_headers()

            def log_message(self, format: str, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", port), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/hooks/secret-token"
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()

    def events(self) -> list[tuple[str, str]]:
        """(event, rule) of each notice received, in order."""
        return [(b["event"], b["alert"]["rule"]) for b in list(self.bodies)]

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    running = Receiver()
    yield running
    running.close()


@contextlib.contextmanager
def alerts_process(
    url: str, topics: Topics, settings: AlertSettings, **kw: Any
) -> Iterator[ServiceThread[AlertsShell]]:
    def make() -> AlertsShell:
        return AlertsShell(url, settings, root=topics.root, webhook_backoff=FAST, tick_s=0.05, **kw)

    with ServiceThread(make, "alerts") as running:
        yield running


def unit_online(probe: MqttProbe, topics: Topics, unit: str) -> None:
    """A unit's `online` and one state, as a unit says them."""
    stamp = HeaderStamper(unit)
    probe.publish(
        topics.unit("connection", unit),
        encode(Connection(header=stamp("connection"), state="online")),
        retain=True,
    )
    unit_state(probe, topics, unit)


def unit_state(probe: MqttProbe, topics: Topics, unit: str) -> None:
    state = UnitState(
        header=HeaderStamper(unit)("state"),
        step=1,
        position=Cell(2, 3),
        direction="-",
        status="idle",
        leds=Leds(),
        sensors=Sensors(N="free", E="free", S="free", W="free"),
    )
    probe.publish(topics.unit("state", unit), encode(state), qos=0, retain=True)


def latest_view(probe: MqttProbe, topics: Topics) -> AlertsView | None:
    seen = probe.received(topics.fleet("alerts"))
    return decode(AlertsView, seen[-1].payload, 8 << 20) if seen else None


def wait_view(probe: MqttProbe, topics: Topics, check: Any, what: str) -> AlertsView:
    def find() -> AlertsView | None:
        view = latest_view(probe, topics)
        return view if view is not None and check(view) else None

    found = wait_for(find, 20.0, what=what)
    assert found is not None
    return found


def ack_request(sender: str, request_id: str, alert_id: str) -> bytes:
    return encode(
        AckAlert(
            header=HeaderStamper(sender)("ack_alert"),
            request_id=request_id,
            reply_to=sender,
            alert_id=alert_id,
        )
    )


def test_a_lost_unit_is_raised_posted_acknowledged_and_cleared(
    broker: Any, topics: Topics, receiver: Receiver
) -> None:
    settings = AlertSettings(**{**QUIET.__dict__, "webhook": receiver.url})
    with (
        MqttProbe(broker.url) as unit,
        MqttProbe(broker.url, "person") as person,
        alerts_process(broker.url, topics, settings),
    ):
        person.subscribe(topics.fleet("alerts"))
        person.subscribe(topics.reply("person"))
        unit_online(unit, topics, "unit1")
        # Silent for longer than unit_lost_s: raised, in the view and at the webhook.
        view = wait_view(person, topics, lambda v: v.active, "the unit lost")
        (alert,) = view.active
        assert (alert.rule, alert.subject, alert.severity) == ("unit_lost", "unit1", "critical")
        wait_for(lambda: receiver.events() == [("raised", "unit_lost")], 20.0, what="the POST")
        assert receiver.bodies[0]["alert"]["id"] == alert.id
        assert receiver.bodies[0]["fleet"] == topics.root

        # Bad acknowledgements: one line each, nothing changes.
        listing = gridfleet("alerts", "--list", "--broker", broker.url, "--root", topics.root)
        assert listing.returncode == 0, listing.stderr
        assert alert.id in listing.stdout and "unit unit1 lost" in listing.stdout
        args = ("--broker", broker.url, "--root", topics.root)
        unknown = gridfleet("alerts", "--ack", "zz-404", *args)
        assert (unknown.returncode, unknown.stdout) == (
            1,
            "refused: no alert 'zz-404': it is neither active nor among the latest cleared\n",
        )
        bad = gridfleet("alerts", "--ack", "has space", *args)
        assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "'has space'" in bad.stderr
        person.publish(topics.request("ack_alert"), b'{"request_id": "r-1", "reply_to": "person"}')
        refused = decode(Reply, person.wait(topics.reply("person")).payload)
        assert (refused.request_id, refused.accepted) == ("r-1", False)
        assert refused.reason is not None and "\n" not in refused.reason
        assert latest_view(person, topics).active[0].acked_by is None  # type: ignore[union-attr]

        # A person acknowledges it (the CLI), then the unit comes back: cleared, acknowledged.
        acked = gridfleet("alerts", "--ack", alert.id, *args)
        assert (acked.returncode, acked.stdout) == (0, f"acknowledged {alert.id}\n")
        view = wait_view(person, topics, lambda v: v.active[0].acked_by, "the acknowledgement")
        assert (view.active[0].acked_by or "").startswith("alerts-cli-")  # no accounts: its id
        unit_state(unit, topics, "unit1")
        view = wait_view(person, topics, lambda v: not v.active, "the alert cleared")
        assert [(a.id, a.rule) for a in view.cleared] == [(alert.id, "unit_lost")]
        assert view.cleared[0].cleared_at is not None and view.cleared[0].acked_by is not None
        wait_for(
            lambda: (
                receiver.events()[:3]
                == [
                    ("raised", "unit_lost"),
                    ("acknowledged", "unit_lost"),
                    ("cleared", "unit_lost"),
                ]
            ),
            20.0,
            what="the acknowledgement and the clear POSTed",
        )


def test_a_receiver_that_is_down_gets_the_alert_once_it_is_up(broker: Any, topics: Topics) -> None:
    port = free_port()
    settings = AlertSettings(**{**QUIET.__dict__, "webhook": f"http://127.0.0.1:{port}/hook"})
    with (
        MqttProbe(broker.url) as operator,
        alerts_process(broker.url, topics, settings, metrics=MetricsOptions(0)) as alerts,
    ):
        operator.publish(topics.fleet("estop"), b"engaged|operator|test", retain=True)
        webhook, server = alerts.service.webhook, alerts.service.metrics_server
        assert webhook is not None and server is not None
        wait_for(lambda: alerts.call(lambda: webhook.failures) >= 2, 20.0, what="failed tries")
        receiver = Receiver(port)
        try:
            wait_for(lambda: receiver.events() == [("raised", "estop")], 20.0, what="the POST")
            assert (
                receiver.bodies[0]["text"] == "[CRITICAL] emergency stop engaged by operator: test"
            )
            # Counted once the receiver's answer is back in the alerts process.
            wait_for(lambda: alerts.call(lambda: webhook.sent) == 1, 20.0, what="one sent")
            scrape = urllib.request.urlopen(server.url, timeout=10).read().decode()
        finally:
            receiver.close()
        operator.publish(topics.fleet("estop"), b"", retain=True)
    lines = set(scrape.splitlines())
    assert 'gridfleet_alerts_active{rule="estop"} 1.0' in lines
    assert 'gridfleet_alerts_unacknowledged{rule="estop"} 1.0' in lines
    assert 'gridfleet_alerts_raised_total{rule="estop"} 1.0' in lines
    assert 'gridfleet_alerts_active{rule="unit_lost"} 0.0' in lines
    assert "gridfleet_alerts_webhook_sent_total 1.0" in lines
    assert any(line.startswith("gridfleet_alerts_webhook_failures_total ") for line in lines)


# ---- with accounts: who acknowledged is the broker's account ---------------------------------


@pytest.fixture(scope="module")
def accounts() -> Accounts:
    viewer = Account("ann", new_password(), "viewer")
    return default_accounts(["unit1"]).with_account(viewer)


@pytest.mark.parametrize("kind", ["amqtt", "mosquitto"])
def test_an_operator_acknowledges_as_their_account_and_a_viewer_cannot(
    kind: str, accounts: Accounts, tmp_path: Path
) -> None:
    topics = Topics(f"t/alerts-accounts-{kind}")
    with contextlib.ExitStack() as stack:
        if kind == "amqtt":
            settings = BrokerSettings(port=0, ws_port=None, accounts=accounts, root=topics.root)
            url = stack.enter_context(BrokerThread(settings)).url
        else:
            url = stack.enter_context(mosquitto_with_accounts(accounts, topics, tmp_path))
        roles = {a.name: a.role for a in accounts.accounts.values()}
        stack.enter_context(
            alerts_process(login(url, accounts, "alerts"), topics, QUIET, accounts=roles)
        )
        unit = stack.enter_context(MqttProbe(login(url, accounts, "unit1"), "unit1"))
        operator = stack.enter_context(
            MqttProbe(login(url, accounts, "operator"), "operator-desk-1")
        )
        viewer = stack.enter_context(MqttProbe(login(url, accounts, "ann"), "ann-laptop"))
        for probe, client in ((operator, "operator-desk-1"), (viewer, "ann-laptop")):
            probe.subscribe(topics.fleet("alerts"))
            probe.subscribe(topics.reply(client))
        unit_online(unit, topics, "unit1")
        (alert,) = wait_view(viewer, topics, lambda v: v.active, "the unit lost").active

        # The broker keeps a viewer off the request topic; the alerts process would refuse it too.
        viewer.publish(topics.request("ack_alert"), ack_request("ann-laptop", "v-1", alert.id))
        operator.publish(
            topics.request("ack_alert"), ack_request("operator-desk-1", "o-1", alert.id)
        )
        reply = decode(Reply, operator.wait(topics.reply("operator-desk-1")).payload)
        assert (reply.request_id, reply.accepted) == ("o-1", True)
        view = wait_view(viewer, topics, lambda v: v.active[0].acked_by, "the acknowledgement")
        assert view.active[0].acked_by == "operator"  # the account, not its client id
        assert viewer.received(topics.reply("ann-laptop")) == []


def test_the_command_runs_the_rules_of_its_config_file(
    broker: Any, topics: Topics, receiver: Receiver, tmp_path: Path
) -> None:
    config = tmp_path / "alerts.toml"
    config.write_text(
        f'[alerts]\ncoordinator_down_s = false\nbroker_down_s = false\nwebhook = "{receiver.url}"\n',
        encoding="utf-8",
    )
    argv = ["alerts", "--broker", broker.url, "--root", topics.root, "--config", str(config)]
    process = subprocess.Popen(
        [sys.executable, "-m", "gridfleet", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        with MqttProbe(broker.url) as person:
            person.subscribe(topics.fleet("alerts"))
            wait_view(person, topics, lambda v: True, "the process's first view")
            person.publish(topics.fleet("estop"), b"engaged|operator|drill", retain=True)
            wait_for(lambda: receiver.events() == [("raised", "estop")], 20.0, what="the POST")
            person.publish(topics.fleet("estop"), b"", retain=True)
    finally:
        process.terminate()
        _, stderr = process.communicate(timeout=30)
    assert process.returncode == 0, stderr
    assert "alert " in stderr and "raised: emergency stop engaged by operator: drill" in stderr
    assert "secret-token" not in stderr  # the webhook's path may hold a secret: never logged


def test_up_refuses_an_alerts_config_without_alerts_in_one_line(tmp_path: Path) -> None:
    config = tmp_path / "alerts.toml"
    config.write_text("[alerts]\n", encoding="utf-8")
    done = gridfleet("up", "--alerts-config", str(config), "--no-robots")
    assert (done.returncode, done.stderr) == (
        2,
        "gridfleet up: error: --alerts-config is for --alerts\n",
    )
    config.write_text("[alerts]\nunit_lost_s = -3\n", encoding="utf-8")
    done = gridfleet("up", "--alerts", "--alerts-config", str(config), "--no-robots")
    assert (done.returncode, done.stderr) == (
        2,
        f"gridfleet up: error: {config}: unit_lost_s -3.0: give a number of seconds > 0, or off\n",
    )


def test_a_restarted_alerts_process_pages_nobody_twice(
    broker: Any, topics: Topics, receiver: Receiver
) -> None:
    # As found: a restart raised the lost unit again under a new id, and the webhook paged twice.
    settings = AlertSettings(**{**QUIET.__dict__, "webhook": receiver.url})
    with MqttProbe(broker.url) as unit, MqttProbe(broker.url, "person") as person:
        person.subscribe(topics.fleet("alerts"))
        unit_online(unit, topics, "unit1")
        with alerts_process(broker.url, topics, settings):
            view = wait_view(person, topics, lambda v: v.active, "the unit lost")
            wait_for(lambda: receiver.events() == [("raised", "unit_lost")], 20.0, what="POST")
        (lost,) = view.active
        with alerts_process(broker.url, topics, settings) as again:
            # Found again (unit1 still silent), it is taken over: same id, no second notice.
            wait_for(lambda: again.call(lambda: again.service.core.settled), 20.0, what="settled")
            latest = latest_view(person, topics)
            assert latest is not None and [a.id for a in latest.active] == [lost.id]
            assert receiver.events() == [("raised", "unit_lost")]
            # The unit comes back: the alert the first run raised is cleared by the second.
            unit_state(unit, topics, "unit1")
            wait_for(
                lambda: receiver.events() == [("raised", "unit_lost"), ("cleared", "unit_lost")],
                20.0,
                what="the cleared notice",
            )
            assert receiver.bodies[-1]["alert"]["id"] == lost.id
