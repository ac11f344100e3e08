"""The adapter's reports on `errors` reach the fleet on a broker with accounts.

As found (issue 53's walkthrough): with `--accounts`, every report of the adapter (a vehicle's
malformed state refused, a release it could not drive, a failed handler) was signed with the
unit's id; a vehicle's unit id is its vehicle account's name, not the adapter's, and the embedded
broker dropped each report ("its header names sender 'agv20', an id account 'vda5050' does not
own"), about one a second, while docs/vda5050.md promised them on `errors`.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from gridfleet.accounts import default_accounts
from gridfleet.grid import GridMap
from gridfleet.protocol import ErrorReport, Topics, decode
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.shell import AdapterShell
from gridfleet.robots.vda5050.wire import Vehicle

from support.mosquitto import broker_with_accounts
from support.probe import MqttProbe
from support.security import VEHICLES, login
from support.wait import async_wait_for

ROOT = "vdaacc"
GRID = GridMap.from_rows(["....", "....", "...."], name="bay")


@pytest.mark.every_broker
async def test_a_malformed_vehicle_state_is_reported_on_errors_with_accounts(
    broker_kind: str, tmp_path: Path
) -> None:
    accounts = default_accounts(["unit1"], list(VEHICLES))
    topics = Topics(ROOT)
    vehicle = Vehicle("agv1", "acme", "sn-1", "2.0.0")
    assert vehicle.prefix == VEHICLES[0].topic
    config = VehicleConfig(vehicle, Frame("bay"), 20.0, 0.0, False)
    with broker_with_accounts(broker_kind, accounts, ROOT, tmp_path) as (url, _):
        adapter = AdapterShell([config], GRID, login(url, accounts, "vda5050"), topics)
        stop = asyncio.Event()
        task = asyncio.create_task(adapter.run(stop))
        try:
            await asyncio.wait_for(adapter.ready.wait(), 30)
            with (
                MqttProbe(login(url, accounts, "operator"), "operator-watch") as watcher,
                MqttProbe(login(url, accounts, "agv1"), "agv1-vendor") as agv,
            ):
                watcher.subscribe(topics.fleet("errors"))
                bad = {"headerId": 1, "driving": "yes"}  # no state: fields missing, one mistyped
                agv.publish(vehicle.topic("state"), json.dumps(bad).encode(), qos=1)

                def reports() -> list[ErrorReport]:
                    got = watcher.received(topics.fleet("errors"))
                    return [decode(ErrorReport, m.payload) for m in got]

                await async_wait_for(lambda: reports() != [], 30, what="the report on errors")
                (report,) = reports()
                assert report.topic == vehicle.topic("state")
                assert report.reason.startswith("vehicle agv1: refused: "), report.reason
                assert report.header.sender.startswith("vda5050-")  # the adapter's own id
        finally:
            stop.set()
            await asyncio.wait_for(task, 30)
