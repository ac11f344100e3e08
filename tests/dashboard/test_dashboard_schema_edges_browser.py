"""The page takes whatever arrives on the topics it follows and keeps showing the fleet (Chromium).

The page (dashboard/static/js/: model.js, main.js and the views) reads every unit's connection,
factsheet, state and vehicle condition, the fleet's views, the stop, error reports, its replies
and its record pages. Batches of messages drawn from each kind's JSON Schema
(support/schema_inputs.py), valid ones and near misses (a field dropped, a value of another type,
an extra key, no JSON at all), go out on those topics; then a good unit state. The page raises no
uncaught exception (`pageerror`) on any of them, and shows the good state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from playwright.sync_api import expect

from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import TOPICS as SPECS
from gridfleet.protocol import Topics

from support.browser import OpenDashboard
from support.fleet_peer import CoordinatorPeer, UnitPeer
from support.probe import MqttProbe
from support.schema_inputs import payloads

pytestmark = pytest.mark.browser

GRID = GridMap.from_rows(["......", "..@...", "......", "......"])
EDGE = 8  # squares on the map and off it, no further: the page's scale is another test's
UNIT_KINDS = ["connection", "factsheet", "state", "vehicle"]
FLEET_KINDS = ["map", "jobs", "routes", "coordinator", "errors", "events", "alerts", "zones"]
CLIENT_KINDS = ["reply", "history_reply", "audit_reply"]
# A map as large as the schema allows would be a test of the page's scale, not of its shapes.
NARROW = {
    "map": {
        ("properties", "width"): {"type": "integer", "minimum": 1, "maximum": EDGE},
        ("properties", "height"): {"type": "integer", "minimum": 1, "maximum": EDGE},
        ("properties", "rows"): {
            "type": "array",
            "maxItems": EDGE,
            "items": {"type": "string", "pattern": f"^[.@]{{1,{EDGE}}}$"},
        },
    },
}
TEXT_KINDS = {  # the stop's payloads: plain text
    "estop": [b"engaged|operator|drill", b"released|operator|", b"maybe|x", b"\xff\xfe", b""],
    "stop": [b"engaged|unit1|bumper", b"released|unit1|x", b"engaged|unit2|not mine", b"{"],
}


def message_on(kind: str, topics: Topics, client: str) -> st.SearchStrategy[tuple[str, str, bytes]]:
    """(kind, topic, payload) of messages on topics of `kind` the page follows."""
    if kind in UNIT_KINDS or kind == "stop":
        where = st.sampled_from(["unit1", "unit2", "ghost"]).map(lambda u: topics.unit(kind, u))
    elif kind in CLIENT_KINDS:
        where = st.just(getattr(topics, kind)(client))  # reply, history_reply, audit_reply
    else:
        where = st.just(topics.fleet(kind))
    if kind in TEXT_KINDS:
        said = st.sampled_from(TEXT_KINDS[kind])
    else:
        said = payloads(kind, max_coord=EDGE, narrow=NARROW.get(kind))
    return st.tuples(st.just(kind), where, said)


def batches(topics: Topics, client: str) -> st.SearchStrategy[list[tuple[str, str, bytes]]]:
    """Lists of messages on every kind the page follows, valid and not."""
    kinds = [*UNIT_KINDS, *FLEET_KINDS, *CLIENT_KINDS, *TEXT_KINDS]
    each = st.one_of([message_on(k, topics, client) for k in kinds])
    return st.lists(each, min_size=30, max_size=60)


@pytest.fixture
def fleet(probe_factory: Callable[..., MqttProbe], topics: Topics) -> tuple[MqttProbe, UnitPeer]:
    """The map and unit1 on [0, 0], as the coordinator and the unit say them."""
    probe = probe_factory()
    CoordinatorPeer(probe, topics).map(GRID)
    unit = UnitPeer(probe, topics, "unit1")
    unit.connection("online")
    unit.factsheet(5.0)
    unit.state(Cell(0, 0))
    return probe, unit


@pytest.mark.timeout(180)  # over 60 s on a slow make test run (fresh clone, 2026-12-02)
def test_the_page_survives_every_shape_of_message_and_shows_the_next_good_one(
    open_dashboard: Callable[..., OpenDashboard],
    fleet: tuple[MqttProbe, UnitPeer],
    topics: Topics,
) -> None:
    probe, unit = fleet
    dash = open_dashboard(grid=GRID)
    page = dash.page
    unit_row = page.locator("#units tr[data-unit='unit1'] .pos")
    expect(unit_row).to_have_text("[0, 0]")
    sent: list[Any] = []
    moves: list[Cell] = [Cell(0, 0)]

    @settings(
        max_examples=6,
        deadline=None,
        database=None,
        derandomize=True,
        # No shrinking: the page keeps what earlier batches left, so a smaller batch is another
        # test; the failing batch is in the assertion.
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    )
    @given(batch=batches(topics, dash.client_id))
    def run(batch: list[tuple[str, str, bytes]]) -> None:
        for kind, topic, payload in batch:
            probe.publish(topic, payload, qos=SPECS[kind].qos, retain=False)
        sent.extend(batch)
        # Then what the fleet says as it is: the map again, and unit1 where it now stands.
        CoordinatorPeer(probe, topics).map(GRID)
        unit.connection("online")
        unit.factsheet(5.0)
        moves.append(Cell(len(moves) % GRID.width, 3))  # a square it was not on before
        square = moves[-1]
        unit.state(square)
        try:
            expect(unit_row).to_have_text(f"[{square.x}, {square.y}]")
        except AssertionError as exc:  # a page that threw stops drawing: say what it threw
            raise AssertionError(f"{dash.errors[:3]} after {batch}: {exc}") from None
        expect(page.locator("#map-name")).not_to_have_text("no map yet")
        assert dash.errors == [], (dash.errors, batch)

    run()
    assert len(sent) >= 6 * 30
    assert dash.errors == []
