"""Across a LAN (network namespaces on one bridge): a unit's link that dies without a word.

The broker and the coordinator run on this machine, unit1 on a host of its own that reaches the
broker by its LAN address, as a robot on Wi-Fi does; accounts are on, as a broker beyond loopback
needs them. The unit's link is cut at the bridge (no FIN, no RST): only the broker's keep-alive
can tell the fleet, on the embedded broker and on Mosquitto alike (protocol.md §4.1, §8).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import pytest

from gridfleet.accounts import Accounts, default_accounts, write_accounts
from gridfleet.bench.lan import Host, Lan
from gridfleet.broker.certs import make_tls, write_tls
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.broker.mosquitto import mosquitto_conf, write_files
from gridfleet.config import with_ca_file
from gridfleet.grid import Cell
from gridfleet.protocol import Topics
from gridfleet.system.broker_thread import BrokerThread

from support.lan import LAN_SCENARIO, Processes
from support.mosquitto import MosquittoBroker, running_mosquitto
from support.operator_peer import OperatorPeer
from support.output import Output
from support.paths import REPO
from support.probe import MqttProbe
from support.security import login
from support.wait import wait_for

# Whole systems waiting out keep-alives: make test, not test-fast, and first in its line. Links
# cut: what the broker does.
pytestmark = [pytest.mark.slow, pytest.mark.every_broker, pytest.mark.waits_first]

GRIDFLEET = [sys.executable, "-m", "gridfleet"]
STEP_S = 0.1
KEEP_ALIVE_S = 10  # gridfleet's clients (gridfleet/bus.py)
# protocol.md §4.1: the broker ends a session silent for 1.5 keep-alives and sends its will.
BROKEN_WITHIN_S = 1.5 * KEEP_ALIVE_S
PARTITION_S = 15.0  # the coordinator's host cut off at least this long: past §8's 10 s failure


@pytest.fixture
def accounts() -> Accounts:
    return default_accounts(["unit1", "unit2"])


@pytest.fixture
def lan_broker(
    request: pytest.FixtureRequest,
    broker: BrokerThread,
    test_lan: Lan,
    accounts: Accounts,
    topics: Topics,
    tmp_path: Path,
) -> Iterator[str]:
    """The kind of broker the test runs on (`broker`'s: amqtt or Mosquitto) with
    accounts, listening on this machine's LAN address; its URL (no credentials). A test may ask
    for TLS (indirect parameter "tls"): a certificate for that address, the CA in the URL."""
    tls = tmp_path / "tls"
    if getattr(request, "param", "plain") == "tls":
        tls.mkdir()
        write_tls(make_tls([test_lan.address]), tls)
    cert, key = (tls / "server.pem", tls / "server.key") if tls.exists() else (None, None)

    def trusted(url: str) -> str:
        return with_ca_file(url, str(tls / "ca.pem")) if tls.exists() else url

    if isinstance(broker, MosquittoBroker):
        passwd, acl = write_files(accounts, topics, tmp_path / "mosquitto")
        with running_mosquitto(
            tmp_path / "mosquitto",
            lambda port: mosquitto_conf(
                passwd, acl, host=test_lan.address, port=port, ws_port=None, tls_cert=cert,
                tls_key=key,
            ),
            host=test_lan.address,
            on=test_lan.command([]),
            inside=test_lan.call,
        ) as port:  # fmt: skip
            yield trusted(f"{'mqtts' if cert else 'mqtt'}://{test_lan.address}:{port}")
        return
    settings = BrokerSettings(
        host=test_lan.address,
        port=0,
        ws_port=None,
        accounts=accounts,
        root=topics.root,
        tls_cert=cert,
        tls_key=key,
    )
    broker = BrokerThread(settings)
    test_lan.call(broker.start)  # its event loop's thread, and so its sockets, on the LAN
    try:
        yield trusted(broker.url)
    finally:
        broker.stop()


def truth_lines(path: Path) -> list[dict[str, object]]:
    """The robots' truth file (`gridfleet robots --truth`), one dict a line."""
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


@dataclass
class LanRun:
    """What every test here starts from: the components' flags (broker, accounts, root), their
    processes, and an operator listening on the broker's host."""

    lan: Lan
    tmp: Path
    common: list[str]
    processes: Processes
    probe: MqttProbe
    operator: OperatorPeer

    def coordinator(self, host: Host | None = None) -> None:
        """The coordinator on `host` (else the broker's), on the playfield's map."""
        self.processes.start(
            "coordinator",
            [*GRIDFLEET, "coordinator", "--map", str(REPO / "maps" / "playfield.map"),
             *self.common, "--step", str(STEP_S), "--db", str(self.tmp / "jobs.db")],
            host=host,
        )  # fmt: skip

    def robots(self, name: str, units: str | None = None, host: Host | None = None) -> None:
        """LAN_SCENARIO's units (or only `units`) on `host`, their truth in `<name>.truth`."""
        scenario = self.tmp / "lan.toml"
        scenario.write_text(LAN_SCENARIO)
        only = [] if units is None else ["--units", units]
        self.processes.start(
            name,
            [*GRIDFLEET, "robots", "--scenario", str(scenario), *only, *self.common,
             "--step", str(STEP_S), "--truth", str(self.tmp / f"{name}.truth")],
            host=host,
        )  # fmt: skip

    def collisions(self, name: str) -> int:
        """What the world of robots `name` counted at its last truth line."""
        lines = truth_lines(self.tmp / f"{name}.truth")
        assert lines, self.processes.tails()
        return int(str(lines[-1]["collisions"]))


@pytest.fixture
def lan_run(
    test_lan: Lan, lan_broker: str, accounts: Accounts, topics: Topics, tmp_path: Path
) -> Iterator[LanRun]:
    """A LanRun on the test's LAN and broker; every process stopped at the end."""
    accounts_file = tmp_path / "accounts.toml"
    write_accounts(accounts, accounts_file)
    common = ["--broker", lan_broker, "--accounts", str(accounts_file), "--root", topics.root]
    processes = Processes(tmp_path, test_lan)
    probe = test_lan.call(MqttProbe(login(lan_broker, accounts, "operator")).connect)
    try:
        yield LanRun(test_lan, tmp_path, common, processes, probe, OperatorPeer(probe, topics))
    finally:
        processes.stop()
        probe.close()


@pytest.mark.parametrize("lan_broker", ["plain", "tls"], indirect=True)
def test_a_units_host_cut_silently_is_broken_its_job_waits_and_it_resumes_in_place(
    lan_run: LanRun, topics: Topics
) -> None:
    probe, operator, processes = lan_run.probe, lan_run.operator, lan_run.processes
    robot = lan_run.lan.host("unit1")
    probe.subscribe(topics.fleet("events"), qos=1)
    lan_run.coordinator()
    lan_run.robots("unit1", "unit1", host=robot)
    lan_run.robots("unit2", "unit2")

    def fail(what: str) -> str:
        heard = {u: operator.connections(u) for u in ("unit1", "unit2")}
        return f"{what}\nconnections {heard}; topics {sorted(probe.messages)}\n{processes.tails()}"

    try:
        wait_for(
            lambda: all(operator.connections(u)[-1:] == ["online"] for u in ("unit1", "unit2")),
            30,
            what="both units online",
        )
        wait_for(operator.coordinator_status, 30, what="the coordinator")
        # 2 kg: unit2 (1 kg) cannot take it, so the job is unit1's and waits for it.
        reply = operator.submit_job(Cell(1, 0), Cell(9, 9), 2.0)
        assert reply.accepted, reply
        job = reply.job_id
        assert job is not None
        wait_for(
            lambda: (s := operator.last_state("unit1")) is not None and s.load_kg > 0,
            30,
            what="unit1 carrying the item",
        )
        # And the coordinator knows it: on a busy machine a late state can count the unit lost a
        # moment before the cut (its job re-queued, then adopted again when it is heard).
        wait_for(
            lambda: operator.job_state(job) in ("loaded", "to_dropoff"),
            30,
            what=f"{job} carried, as the coordinator lists it",
        )
    except Exception as exc:
        raise AssertionError(fail(str(exc))) from exc

    # The unit's host falls off the LAN without a word.
    robot.cut()
    cut_at = time.monotonic()
    views_at_cut = len(operator.job_views())
    before = operator.last_state("unit1")
    assert before is not None
    try:
        wait_for(
            lambda: operator.connections("unit1")[-1:] == ["broken"],
            BROKEN_WITHIN_S + 30,
            what="unit1 broken",
        )
    except Exception as exc:
        raise AssertionError(fail(str(exc))) from exc
    broken_after = time.monotonic() - cut_at
    # The will, sent by the broker's keep-alive (1.5 x 10 s), and not much later (Mosquitto
    # looks at keep-alives every few seconds: 20.9 s seen in CI); never sooner than a
    # keep-alive (it is the broker's, not a client's, doing).
    assert KEEP_ALIVE_S <= broken_after <= BROKEN_WITHIN_S + 10, broken_after
    events = [m.payload.decode() for m in probe.received(topics.fleet("events"))]
    assert any("unit unit1 lost" in e for e in events), events
    # §8: the item is on board, so the job waits for the unit, nobody else can finish it;
    # gone for 20 loss timeouts (at least 10 s), it fails.
    try:
        wait_for(lambda: operator.job_state(job) == "failed", 60, what=f"{job} failed")
    except Exception as exc:
        raise AssertionError(fail(str(exc))) from exc
    view = operator.listed_jobs()[job]
    assert view.unit == "unit1", view
    assert "carrying the item" in (view.reason or ""), view
    since_cut = operator.job_views()[views_at_cut:]
    shown = [j.state for v in since_cut for j in v.listed() if j.id == job]
    assert "queued" not in shown, shown  # never put back in the queue for another
    left_at = before.position

    # Plugged in again: it comes back by itself where it stood, and puts the item of the
    # failed job down at its pickup (§8, stray items).
    robot.heal()
    try:
        wait_for(
            lambda: operator.connections("unit1")[-1:] == ["online"],
            60,
            what="unit1 online again",
        )
        wait_for(
            lambda: (
                (s := operator.last_state("unit1")) is not None
                and s.load_kg == 0
                and s.position == Cell(1, 0)
            ),
            60,
            what="the item put down at the pickup",
        )
    except Exception as exc:
        raise AssertionError(fail(str(exc))) from exc
    back = [s for s in operator.states("unit1") if s.step > before.step]
    assert back, "no state after the cut"
    # No teleport: within the squares it had been released, which it may have driven unheard.
    first_back = back[0].position
    assert abs(first_back.x - left_at.x) + abs(first_back.y - left_at.y) <= 2, (
        left_at,
        first_back,
    )
    assert operator.listed_jobs()[job].state == "failed"  # never done twice, nor by another

    processes.stop()  # each world's last truth line is written on the way out
    assert [lan_run.collisions(unit) for unit in ("unit1", "unit2")] == [0, 0]


# A short Wi-Fi hang the session outlives, and one longer than the broker's keep-alive: the
# device's session ends, and the press must come over the next one, once.
@pytest.mark.parametrize("stall_s", [8.0, BROKEN_WITHIN_S + 5], ids=["short", "past-keep-alive"])
def test_a_press_on_a_device_whose_link_stalls_arrives_once_when_it_returns(
    stall_s: float, lan_run: LanRun, topics: Topics
) -> None:
    probe = lan_run.probe
    press, link = topics.device("device_stop", "device-unit1"), "device-unit1"
    panel = lan_run.lan.host("panel")
    with ExitStack() as stack:
        probe.subscribe(press, qos=1)
        probe.subscribe(topics.device("device_connection", link), qos=1)
        probe.subscribe(topics.fleet("estop"), qos=1)
        lan_run.coordinator()
        device = subprocess.Popen(
            panel.command([*GRIDFLEET, "device", "--unit", "unit1", *lan_run.common]),
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=REPO,
            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
        stack.callback(device.kill)  # (a no-op once it has exited)
        shown = Output(device)
        shown.wait(r"link=online", 30)
        wait_for(
            lambda: probe.received(topics.device("device_connection", link)), 30, what="online"
        )

        panel.stall()
        assert device.stdin is not None
        device.stdin.write("s\n")
        device.stdin.flush()
        shown.wait(r"leds=#### .*stop=pending", 10)  # shown at once, still being sent
        stalled_until = time.monotonic() + stall_s
        wait_for(lambda: time.monotonic() > stalled_until, stall_s + 1, what="the stall's end")
        assert probe.received(press) == []  # nothing got through the stall
        panel.heal()

        arrived = wait_for(lambda: probe.received(press), 30, what="the press")
        assert arrived[0].payload == b"engaged|device-unit1|button"
        # The coordinator latches it: the fleet is stopped by the device.
        wait_for(
            lambda: any(
                m.payload.startswith(b"engaged|device-unit1")
                for m in probe.received(topics.fleet("estop"))
            ),
            30,
            what="the latch engaged by the device",
        )
        # The device's own press came back to it: no longer pending.
        wait_for(lambda: "stop=pending" not in shown.lines[-1], 30, what="the press confirmed")
        # A clean exit says offline after everything it sent before: every press has arrived.
        device.send_signal(signal.SIGTERM)
        assert device.wait(15) == 0
        probe.wait(topics.device("device_connection", link), lambda m: m.payload == b"offline")
        assert [m.payload for m in probe.received(press)] == [b"engaged|device-unit1|button"]


def test_a_coordinator_cut_off_from_the_broker_holds_every_unit_until_it_is_back(
    lan_run: LanRun,
) -> None:
    operator, processes = lan_run.operator, lan_run.processes
    office = lan_run.lan.host("coord")
    units = ("unit1", "unit2")
    lan_run.coordinator(host=office)
    lan_run.robots("robots")

    def fail(what: str) -> str:
        return f"{what}\n{processes.tails()}"

    def status() -> str | None:
        now = operator.coordinator_status()
        return None if now is None else now.state

    try:
        wait_for(
            lambda: all(operator.connections(u)[-1:] == ["online"] for u in units),
            30,
            what="both units online",
        )
        wait_for(lambda: status() == "online", 30, what="the coordinator online")
        # A long job for each (unit2 carries 1 kg at most).
        replies = [
            operator.submit_job(Cell(1, 0), Cell(9, 9), 2.0),
            operator.submit_job(Cell(8, 0), Cell(0, 9), 1.0),
        ]
        jobs = [r.job_id for r in replies if r.job_id is not None]
        assert len(jobs) == 2, replies
        # Both items on board: only these units can finish these jobs (§8).
        wait_for(
            lambda: all((s := operator.last_state(u)) is not None and s.load_kg > 0 for u in units),
            60,
            what="both units carrying their items",
        )
    except Exception as exc:
        raise AssertionError(fail(str(exc))) from exc

    # The coordinator's host falls off the LAN; the units still reach the broker.
    office.cut()
    cut_at = time.monotonic()
    try:
        # §8: without orders for 3 steps a unit holds still (after the squares it was given).
        wait_for(
            lambda: all(
                (s := operator.last_state(u)) is not None
                and s.status == "holding"
                and "no order" in (s.wait_reason or "")
                for u in units
            ),
            15,
            what="both units holding",
        )
        held = {u: operator.states(u)[-1] for u in units}
        # Cut off while an item was on board (a unit that had already delivered would leave its
        # job nothing to fail by).
        assert any(held[u].load_kg > 0 for u in units), held
        # Cut off until the broker gives up on it (its will), and past a carried job's failure
        # timeout (20 loss timeouts, 10 s): hearing nobody, not even its own status, the
        # coordinator takes the silence for its own, not its units' (protocol.md §8).
        until = cut_at + PARTITION_S
        wait_for(lambda: status() == "broken", 40, what="the coordinator's will")
        wait_for(lambda: time.monotonic() > until, PARTITION_S + 1, what="the partition's end")
    except Exception as exc:
        raise AssertionError(fail(str(exc))) from exc
    for unit in units:
        since = [s for s in operator.states(unit) if s.step >= held[unit].step]
        assert {s.position for s in since} == {held[unit].position}, (unit, since)

    # Back on the LAN: it carries on by itself and the fleet finishes both jobs.
    office.heal()
    try:
        wait_for(lambda: status() == "online", 60, what="the coordinator online")
        wait_for(lambda: operator.all_final(jobs), 90, what="both jobs over")
    except Exception as exc:
        raise AssertionError(fail(str(exc))) from exc
    assert [operator.job_state(j) for j in jobs] == ["done", "done"]

    processes.stop()  # the world's last truth line is written on the way out
    assert lan_run.collisions("robots") == 0
