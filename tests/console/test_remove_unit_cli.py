"""`gridfleet job remove UNIT` over a broker with accounts (the embedded amqtt and Mosquitto): an
online unit refused, a lost one removed, its retained topics cleared by the coordinator's account
(`gridfleet status` shows it gone), the act audited, and the unit back later as a new one."""

from __future__ import annotations

import asyncio
import subprocess
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from gridfleet.accounts import Accounts, default_accounts, write_accounts
from gridfleet.console.audit import read_trail
from gridfleet.coordinator.audit import Identity
from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import Topics
from gridfleet.system.threads import ServiceThread

from support.cli import gridfleet
from support.fleet_peer import UnitPeer
from support.mosquitto import broker_with_accounts
from support.probe import MqttProbe
from support.security import login
from support.wait import wait_for

# The coordinator's clears pass the broker's ACL, and the retained copies go: the broker's own
# doing, on each broker.
pytestmark = pytest.mark.every_broker

ROOT = "removal"
T = Topics(ROOT)
GRID = GridMap.from_rows(["......", "......"], name="dock")


@pytest.fixture
def fleet(
    broker_kind: str, tmp_path: Path
) -> Iterator[tuple[str, Accounts, Path, ServiceThread[CoordinatorShell]]]:
    """(broker URL without a login, the accounts, their file, the coordinator on its account)."""
    accounts = default_accounts(["hv1", "u2"])
    path = tmp_path / "accounts.toml"
    write_accounts(accounts, path)
    (tmp_path / "mosquitto").mkdir()
    with broker_with_accounts(broker_kind, accounts, ROOT, tmp_path / "mosquitto") as (
        url,
        vouched,
    ):

        def make() -> CoordinatorShell:
            return CoordinatorShell(
                login(url, accounts, "coordinator"),
                GRID,
                root=ROOT,
                step_s=0.2,
                db_path=tmp_path / "db",
                identity=Identity(accounts, vouched=vouched),
            )

        with ServiceThread(make, "removal-coordinator") as coordinator:
            yield url, accounts, path, coordinator


def cli(url: str, path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """`gridfleet ARGS` as the operator account, on this test's broker and root."""
    return gridfleet(*args, "--broker", url, "--root", ROOT, "--accounts", str(path))


def status_lines(url: str, path: Path) -> list[str]:
    """`gridfleet status --once`: the units it lists, one line each (and the count)."""
    out = cli(url, path, "status", "--once")
    assert out.returncode == 0, out.stderr
    return [
        line for line in out.stdout.splitlines() if line.startswith(("units:", "  hv1", "  u2"))
    ]


def test_a_lost_unit_is_removed_for_good_and_comes_back_only_as_new(
    fleet: tuple[str, Accounts, Path, ServiceThread[CoordinatorShell]],
) -> None:
    url, accounts, path, coordinator = fleet
    world = coordinator.service.world
    with (
        MqttProbe(login(url, accounts, "hv1")) as hv1_probe,
        MqttProbe(login(url, accounts, "u2")) as u2_probe,
    ):
        hv1, u2 = UnitPeer(hv1_probe, T, "hv1"), UnitPeer(u2_probe, T, "u2")
        for peer, square in ((hv1, Cell(3, 0)), (u2, Cell(0, 0))):
            peer.connection("online")
            peer.factsheet(5.0, step_period_s=10.0)  # heard from for 50 s after its last state
            peer.state(square)
        wait_for(
            lambda: {"hv1", "u2"} <= {u for u, r in world.units.items() if r.state is not None},
            timeout=20,
            what="both units known to the coordinator",
        )
        online = cli(url, path, "job", "remove", "u2")
        assert online.returncode == 1, online.stderr
        assert online.stdout.strip() == (
            "refused: unit u2 is online and heard from: only a lost unit (offline, broken or "
            "silent) can be removed; take it out of service and switch it off first"
        )
        hv1.connection("offline")  # switched off on its square, then carried away
        wait_for(lambda: world.units["hv1"].connection == "offline", timeout=20, what="offline")
        removed = cli(url, path, "job", "remove", "hv1", "--reason", "carried off the floor")
        assert (removed.returncode, removed.stdout.strip()) == (
            0,
            "accepted: unit hv1 removed; it had no job",
        ), removed.stderr
        assert "hv1" not in world.units
        removals = coordinator.service.core.removals
        wait_for(
            lambda: removals.units["hv1"].cleared,
            timeout=20,
            what="the coordinator's clear of hv1's connection heard back",
        )
        # Its retained topics are gone from the broker: the status lists u2 alone.
        wait_for(
            lambda: status_lines(url, path)[0] == "units: 1, 1 online",
            timeout=20,
            interval=0.5,
            what="hv1 gone from the status",
        )
        since = datetime.now(UTC) - timedelta(hours=1)
        trail = asyncio.run(
            read_trail(login(url, accounts, "operator"), T, since, None, None, 10.0)
        )
        acts = [(e.act, e.target, e.outcome, e.actor) for e in trail if e.act == "remove_unit"]
        assert acts == [
            ("remove_unit", "u2", "refused", "operator"),
            ("remove_unit", "hv1", "accepted", "operator"),
        ]
        # Back (reconnected, elsewhere): a new unit, its square judged as any new unit's.
        hv1.connection("online")
        hv1.factsheet(5.0, step_period_s=10.0)
        hv1.state(Cell(5, 1))
        wait_for(
            lambda: "hv1" in world.units and world.units["hv1"].position == Cell(5, 1),
            timeout=20,
            what="hv1 joined again as new",
        )
        assert "hv1" not in removals
        wait_for(
            lambda: status_lines(url, path)[0] == "units: 2, 2 online",
            timeout=20,
            interval=0.5,
            what="hv1 in the status again",
        )
