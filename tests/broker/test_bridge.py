"""A hall broker bridged to the central one (Mosquitto's bridge, as `gridfleet accounts mosquitto
--bridge-to` writes it): the playfield's units on the hall's broker, on a host of the test LAN; the
coordinator and the people on the central broker. The bridge is cut mid-run and healed."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import pytest

from gridfleet.accounts import Account, Accounts, default_accounts, new_password, write_accounts
from gridfleet.bench.lan import Host, Lan
from gridfleet.broker.certs import make_tls, write_tls
from gridfleet.broker.mosquitto import bridge_conf, mosquitto_conf, write_files
from gridfleet.config import with_ca_file
from gridfleet.protocol import Topics, decode_estop
from gridfleet.scenario import load_scenario

from support.lan import Processes
from support.mosquitto import running_mosquitto
from support.operator_peer import OperatorPeer
from support.paths import REPO
from support.probe import MqttProbe
from support.security import login
from support.wait import wait_for

pytestmark = pytest.mark.slow  # a whole fleet across two brokers: make test, not test-fast

PLAYFIELD = REPO / "maps" / "playfield.toml"
UNITS = [u.id for u in load_scenario(PLAYFIELD).units]
GRIDFLEET = [sys.executable, "-m", "gridfleet"]
STEP_S = 0.1


@dataclass
class Site:
    """The two brokers' URLs (no credentials), the hall's host and the accounts file."""

    central: str
    hall: str
    lan: Lan
    hall_host: Host
    accounts: Accounts
    accounts_file: Path


@pytest.fixture(params=["plain", "tls"])
def site(
    request: pytest.FixtureRequest, test_lan: Lan, topics: Topics, tmp_path: Path
) -> Iterator[Site]:
    """Central Mosquitto on this machine's LAN address; the hall's on its host, bridged to it
    (over TLS to the central broker, with the "tls" parameter: its certificate for that address)."""
    tls = tmp_path / "tls" if request.param == "tls" else None
    if tls is not None:
        tls.mkdir()
        write_tls(make_tls([test_lan.address]), tls)
    cert, key = (None, None) if tls is None else (tls / "server.pem", tls / "server.key")
    accounts = default_accounts(UNITS).with_account(Account("hall1", new_password(), "bridge"))
    accounts_file = tmp_path / "accounts.toml"
    write_accounts(accounts, accounts_file)
    hall = test_lan.host("hall")
    central_dir, hall_dir = tmp_path / "central", tmp_path / "hall"
    with ExitStack() as stack:
        passwd, acl = write_files(accounts, topics, central_dir)
        central_port = stack.enter_context(
            running_mosquitto(
                central_dir,
                lambda port: mosquitto_conf(
                    passwd,
                    acl,
                    host=test_lan.address,
                    port=port,
                    ws_port=None,
                    tls_cert=cert,
                    tls_key=key,
                ),
                host=test_lan.address,
                on=test_lan.command([]),
                inside=test_lan.call,
            )
        )
        hall_passwd, hall_acl = write_files(accounts, topics, hall_dir)
        bridge = bridge_conf(
            accounts.get("hall1"),
            test_lan.address,
            central_port,
            topics,
            None if tls is None else tls / "ca.pem",
        )
        hall_port = stack.enter_context(
            running_mosquitto(
                hall_dir,
                lambda port: (
                    mosquitto_conf(
                        hall_passwd, hall_acl, host=hall.address, port=port, ws_port=None
                    )
                    + bridge
                ),
                host=hall.address,
                on=hall.command([]),
                inside=test_lan.call,
            )
        )
        central = f"{'mqtt' if tls is None else 'mqtts'}://{test_lan.address}:{central_port}"
        yield Site(
            central if tls is None else with_ca_file(central, str(tls / "ca.pem")),
            f"mqtt://{hall.address}:{hall_port}",
            test_lan,
            hall,
            accounts,
            accounts_file,
        )


def test_the_playfield_finishes_across_a_bridge_and_a_bridge_cut_loses_nothing(
    site: Site, topics: Topics, tmp_path: Path
) -> None:
    common = ["--accounts", str(site.accounts_file), "--root", topics.root, "--step", str(STEP_S)]
    with ExitStack() as stack:
        processes = Processes(tmp_path, site.lan)
        stack.callback(processes.stop)

        def fail(what: str) -> str:
            return f"{what}\n{processes.tails()}"

        probe = site.lan.call(MqttProbe(login(site.central, site.accounts, "operator")).connect)
        stack.callback(probe.close)
        operator = OperatorPeer(probe, topics)
        probe.subscribe(topics.fleet("events"), qos=1)
        processes.start(
            "coordinator",
            [*GRIDFLEET, "coordinator", "--map", str(REPO / "maps" / "playfield.map"),
             "--broker", site.central, *common, "--db", str(tmp_path / "jobs.db")],
        )  # fmt: skip
        processes.start(
            "robots",
            [*GRIDFLEET, "robots", "--scenario", str(PLAYFIELD), "--broker", site.hall,
             *common, "--truth", str(tmp_path / "robots.truth")],
            site.hall_host,
        )  # fmt: skip
        try:
            # The hall's units, heard on the central broker across the bridge.
            wait_for(
                lambda: all(operator.connections(u)[-1:] == ["online"] for u in UNITS),
                30,
                what="every unit online on the central broker",
            )
            wait_for(operator.coordinator_status, 30, what="the coordinator")
            jobs = []
            for job in load_scenario(PLAYFIELD).jobs:
                reply = operator.submit_job(job.pickup, job.dropoff, job.mass)
                assert reply.accepted and reply.job_id is not None, reply
                jobs.append(reply.job_id)
            wait_for(
                lambda: any(operator.job_state(j) == "done" for j in jobs),
                60,
                what="a first job done across the bridge",
            )
        except Exception as exc:
            raise AssertionError(fail(str(exc))) from exc

        # The bridge is cut (the hall's link, no word to either side), and the stop is engaged
        # on the central broker meanwhile: after the heal the hall must have it.
        site.hall_host.cut()
        heard = len(operator.states(UNITS[0]))
        try:
            wait_for(
                lambda: any(
                    "lost" in m.payload.decode() for m in probe.received(topics.fleet("events"))
                ),
                30,
                what="the coordinator treating the hall's units as lost",
            )
        except Exception as exc:
            raise AssertionError(fail(str(exc))) from exc
        assert len(operator.states(UNITS[0])) <= heard + 1  # nothing crossed the cut
        operator.engage("stop during the bridge cut")
        site.hall_host.heal()

        hall_probe = site.lan.call(MqttProbe(login(site.hall, site.accounts, "operator")).connect)
        stack.callback(hall_probe.close)
        hall_probe.subscribe(topics.fleet("estop"), qos=1)
        hall_probe.subscribe(topics.all_units("state"), qos=0)
        try:
            # The latch crossed to the hall: retained there, and every unit stopped by it.
            wait_for(
                lambda: (
                    (m := hall_probe.received(topics.fleet("estop")))
                    and decode_estop(m[-1].payload).engaged
                ),
                60,
                what="the engaged latch on the hall's broker",
            )
            wait_for(
                lambda: all(
                    (s := operator.last_state(u)) is not None and s.status == "stopped"
                    for u in UNITS
                ),
                60,
                what="every unit stopped, as the central broker hears it",
            )
        except Exception as exc:
            raise AssertionError(fail(str(exc))) from exc
        stopped_at = {u: operator.last_state(u) for u in UNITS}
        operator.release("bridge healed")
        try:
            wait_for(
                lambda: (
                    (m := hall_probe.received(topics.fleet("estop")))
                    and not decode_estop(m[-1].payload).engaged
                ),
                30,
                what="the release on the hall's broker",
            )
            wait_for(lambda: operator.all_final(jobs), 120, what="every job over")
        except Exception as exc:
            raise AssertionError(fail(str(exc))) from exc
        assert [operator.job_state(j) for j in jobs] == ["done"] * len(jobs)
        # Stopped units stayed where the stop found them until the release.
        for unit, state in stopped_at.items():
            assert state is not None
            until_release = [
                s for s in operator.states(unit) if s.step >= state.step and s.status == "stopped"
            ]
            assert {s.position for s in until_release} == {state.position}, unit

    lines = [json.loads(x) for x in (tmp_path / "robots.truth").read_text().splitlines() if x]
    assert lines and lines[-1]["collisions"] == 0
