"""The page given two brokers (a cluster's nodes, here two embedded brokers over websockets):
when the one it is on dies it moves to the other, says so, and shows the fleet again."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from playwright.sync_api import expect

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol import Topics
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread

from support.browser import OpenDashboard
from support.fleet_peer import CoordinatorPeer, UnitPeer
from support.paths import MAPS
from support.probe import MqttProbe

pytestmark = pytest.mark.browser


def test_the_page_moves_to_the_next_broker_when_its_own_dies(
    open_dashboard: Callable[..., OpenDashboard], topics: Topics
) -> None:
    grid: GridMap = load_scenario(MAPS / "playfield.toml").grid
    with BrokerThread() as first, BrokerThread() as second:
        # Two brokers that share nothing: what the page shows after the move is the second's.
        for broker, square, step in ((first, Cell(0, 0), 1), (second, Cell(2, 0), 5)):
            with MqttProbe(broker.url) as probe:
                CoordinatorPeer(probe, topics).map(grid)
                UnitPeer(probe, topics, "unit1").state(square, step=step)
        dash = open_dashboard(via=first, broker_ws=f"{first.ws_url},{second.ws_url}")
        second.allow_origins(dash.server.url)  # its port known only now
        conn = dash.page.locator("#conn")
        position = dash.page.locator("#units tr[data-unit='unit1'] .pos")
        expect(conn).to_have_text(f"broker: connected to 127.0.0.1:{first.ws_port}")
        expect(position).to_have_text("[0, 0]")

        first.stop()
        expect(conn).to_have_text(f"broker: connected to 127.0.0.1:{second.ws_port}")
        expect(conn).to_have_attribute("data-state", "connected")
        expect(position).to_have_text("[2, 0]")  # the fleet again, as the second broker has it
        with MqttProbe(second.url) as probe:  # and subscribed there: what comes next shows
            UnitPeer(probe, topics, "unit1").state(Cell(3, 0), Direction.E, "moving", step=6)
            expect(position).to_have_text("[3, 0]")
    assert dash.errors == []
