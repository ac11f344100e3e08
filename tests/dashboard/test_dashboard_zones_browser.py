"""Places and closed zones on the page (issue 55), in real Chromium against the real broker.

The test plays the coordinator: it publishes the retained `fleet/map` with named places and the
retained `fleet/zones`, and reads what the page publishes. The map writes each place's name and
marks its kinds, and draws each closed zone; the job form offers the places and a click on the
map picks the place there; the job tables name the places; a unit's status says its route's
note; a drag over the map in the zone mode closes a zone (`requests/close_zone`, exactly as its
schema has it) and "Open" opens one (`requests/open_zone`); refusals show in words; a zones
view that breaks its schema changes nothing; a viewer's page lists the zones without buttons.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from typing import Any

import pytest
from playwright.sync_api import expect

from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import (
    Charger,
    CloseZone,
    FleetMap,
    HeaderStamper,
    JobView,
    OpenZone,
    Place,
    RouteView,
    SubmitJob,
    Topics,
    Zone,
    ZonesView,
    decode,
)
from gridfleet.scenario import load_scenario

from support.browser import OpenDashboard, wait_in_page
from support.fleet_peer import CoordinatorPeer, UnitPeer, publish
from support.paths import MAPS
from support.probe import MqttProbe
from support.schema_inputs import allowed, parsed

pytestmark = pytest.mark.browser

PLAYFIELD = MAPS / "playfield.toml"
PLACES = [  # free squares of the playfield
    Place(name="A3", square=Cell(3, 4), kinds=["pickup"]),
    Place(name="A4", square=Cell(5, 5), kinds=["pickup", "dropoff"]),
    Place(name="P2", square=Cell(8, 8), kinds=["dropoff"]),
    Place(name="park-1", square=Cell(0, 5), kinds=["parking"]),
    Place(name="C1", square=Cell(9, 4), kinds=["charger"]),
]
DOCK = Zone(
    name="dock",
    first=Cell(7, 0),
    last=Cell(9, 1),
    reason="spill: wet floor",
    closed_by="operator",
    closed_at=datetime(2026, 11, 21, 10, 0, 43, tzinfo=UTC),
)


@pytest.fixture
def probe(probe_factory: Callable[..., MqttProbe], topics: Topics) -> MqttProbe:
    """The coordinator's connection: it publishes the views, and hears the page's requests."""
    probe = probe_factory()
    for kind in ("submit_job", "close_zone", "open_zone"):
        probe.subscribe(topics.request(kind))
    return probe


@pytest.fixture
def stamp() -> HeaderStamper:
    return HeaderStamper("coordinator")


@pytest.fixture
def coordinator_peer(probe: MqttProbe, topics: Topics) -> CoordinatorPeer:
    """Replies, the queue view and the routes, as the coordinator publishes them."""
    return CoordinatorPeer(probe, topics)


def publish_map(probe: MqttProbe, topics: Topics, stamp: HeaderStamper) -> None:
    """The playfield's `fleet/map` with its places and a charger, as the coordinator says it."""
    grid: GridMap = load_scenario(PLAYFIELD).grid
    message = FleetMap(
        header=stamp("map"),
        name=grid.name,
        width=grid.width,
        height=grid.height,
        rows=grid.rows(),
        chargers=[Charger(name="C1", square=Cell(9, 4))],
        places=PLACES,
    )
    publish(probe, "map", topics.fleet("map"), message)


def publish_zones(
    probe: MqttProbe, topics: Topics, stamp: HeaderStamper, zones: Sequence[Zone]
) -> None:
    """The retained `fleet/zones`."""
    publish(
        probe, "zones", topics.fleet("zones"), ZonesView(header=stamp("zones"), zones=list(zones))
    )


@pytest.fixture
def dash(
    open_dashboard: Callable[..., OpenDashboard],
    probe: MqttProbe,
    topics: Topics,
    stamp: HeaderStamper,
) -> OpenDashboard:
    """The page on the playfield with its places, unit1 on [0, 0] and the dock zone closed."""
    publish_map(probe, topics, stamp)
    publish_zones(probe, topics, stamp, [DOCK])
    unit = UnitPeer(probe, topics, "unit1")
    unit.connection("online")
    unit.factsheet(5.0)
    unit.state(Cell(0, 0))
    dash = open_dashboard()
    expect(dash.page.locator("#map-name")).to_have_text("playfield 10 x 10")
    expect(dash.page.locator("#zones tr[data-zone='dock']")).to_have_count(1)
    return dash


def square_point(dash: OpenDashboard, square: tuple[int, int]) -> tuple[float, float]:
    """The page's coordinates of the centre of `square` on the map canvas."""
    canvas = dash.page.locator("#map")
    wait_in_page(dash.page, "document.querySelector('#map').dataset.cell !== undefined")
    box = canvas.bounding_box()
    assert box is not None
    cell, ox, oy = (float(canvas.get_attribute(f"data-{k}") or "nan") for k in ("cell", "ox", "oy"))
    return box["x"] + ox + (square[0] + 0.5) * cell, box["y"] + oy + (square[1] + 0.5) * cell


def drag(dash: OpenDashboard, start: tuple[int, int], end: tuple[int, int]) -> None:
    """Press on square `start`, move over the map to square `end` and let go there."""
    mouse = dash.page.mouse
    mouse.move(*square_point(dash, start))
    mouse.down()
    x, y = square_point(dash, end)
    mouse.move(x, y, steps=8)
    mouse.up()


def zone_row(dash: OpenDashboard, name: str) -> list[str]:
    """The zones list's cells of zone `name`, as shown."""
    cells: list[str] = dash.page.locator(f"#zones tr[data-zone='{name}'] td").all_inner_texts()
    return cells


def test_places_are_drawn_offered_picked_by_a_click_and_named_in_the_tables(
    dash: OpenDashboard,
    probe: MqttProbe,
    coordinator_peer: CoordinatorPeer,
    topics: Topics,
) -> None:
    page = dash.page
    canvas = page.locator("#map")
    expect(canvas).to_have_attribute(
        "data-places",
        "A3@3,4:pickup A4@5,5:pickup+dropoff C1@9,4:charger P2@8,8:dropoff park-1@0,5:parking",
    )
    # Every name written on its square (the charger's is the charger's own label).
    expect(canvas).to_have_attribute("data-place-names", "A3 A4 P2 park-1")
    pickups = page.locator("#pickup-places option")
    expect(pickups).to_have_count(2)
    assert [o.get_attribute("value") for o in pickups.all()] == ["A3", "A4"]
    assert page.locator("#dropoff-places option").evaluate_all("os => os.map(o => o.value)") == [
        "A4",
        "P2",
    ]
    assert page.locator("#pickup-places option").first.text_content() == "[3, 4]"

    # A click picks the place on its square; a dropoff place is no pickup: its square instead.
    page.locator("input[name=clickmode][value=job]").check()
    form = page.locator("#job-form")
    dash.click_square(8, 8)
    expect(form.locator("input[name=pickup]")).to_have_value("8,8")
    dash.click_square(8, 8)
    expect(form.locator("input[name=dropoff]")).to_have_value("P2")
    expect(page.locator("#job-feedback")).to_have_text(
        "dropoff P2 [8, 8]: set the mass and press “queue job”"
    )
    form.locator("input[name=pickup]").focus()  # the focused field takes the next click
    dash.click_square(3, 4)
    expect(form.locator("input[name=pickup]")).to_have_value("A3")
    expect(form.locator("input[name=dropoff]")).to_have_value("P2")
    form.locator("input[name=mass]").fill("2.5")
    form.locator("button[type=submit]").click()
    request = decode(SubmitJob, probe.wait(topics.request("submit_job")).payload)
    assert (request.pickup, request.dropoff, request.mass_kg) == ("A3", "P2", 2.5)
    expect(page.locator("#job-feedback")).to_contain_text("job A3 [3, 4] → P2 [8, 8], 2.5 kg")

    # A name of the wrong kind is refused on the page, and nothing more is sent.
    form.locator("input[name=pickup]").fill("P2")
    form.locator("button[type=submit]").click()
    expect(page.locator("#job-feedback")).to_have_text(
        "pickup: place P2 is not a pickup (it is: dropoff); the pickups are A3, A4"
    )

    # The tables name the places; the unit's status says its route's note.
    named = JobView(
        id="job-1",
        state="to_pickup",
        unit="unit1",
        pickup=Cell(3, 4),
        dropoff=Cell(8, 8),
        mass_kg=2.5,
        pickup_place="A3",
        dropoff_place="P2",
    )
    square = named.model_copy(update={"id": "job-2", "state": "done", "pickup_place": None})
    coordinator_peer.jobs([named, square])
    expect(page.locator("#jobs tr[data-job='job-1'] .route")).to_have_text("A3 [3, 4] → P2 [8, 8]")
    expect(page.locator("#finished tr[data-job='job-2'] .route")).to_have_text("[3, 4] → P2 [8, 8]")
    note = "leaving zone dock (closed: spill: wet floor)"
    coordinator_peer.routes({"unit1": RouteView(note=note)})
    expect(page.locator("#units tr[data-unit='unit1'] .status")).to_contain_text(note)
    sent = {m.payload for m in probe.received(topics.request("submit_job"))}
    assert len(sent) == 1, "the refused name sent nothing"
    assert dash.errors == []


def test_a_drag_closes_a_zone_and_open_opens_one_with_their_refusals_in_words(
    dash: OpenDashboard,
    probe: MqttProbe,
    coordinator_peer: CoordinatorPeer,
    topics: Topics,
    stamp: HeaderStamper,
) -> None:
    page = dash.page
    canvas = page.locator("#map")
    # The zone closed already: drawn, and listed with who closed it and why.
    expect(canvas).to_have_attribute("data-zones", "dock@7,0-9,1")
    expect(page.locator("#zones-count")).to_have_text("(1)")
    assert zone_row(dash, "dock")[:4] == [
        "dock",
        "[7, 0] to [9, 1] (3 x 2 squares)",
        "spill: wet floor",
        "operator",
    ]

    # From the lower right corner to the upper left: the rectangle's corners come out least first.
    page.locator("input[name=clickmode][value=zone]").check()
    drag(dash, (4, 6), (2, 1))
    expect(canvas).to_have_attribute("data-draft", "2,1-4,6")
    zone_form = page.locator("#zone-form")
    expect(zone_form).to_be_visible()
    expect(page.locator("#zone-rect")).to_have_text("close [2, 1] to [4, 6] (3 x 6 squares):")
    expect(zone_form.locator("input[name=name]")).to_be_focused()
    zone_form.locator("input[name=name]").fill("aisle-4")
    zone_form.locator("input[name=reason]").fill("   ")  # no reason: refused here, nothing sent
    zone_form.locator("button[type=submit]").click()
    expect(page.locator("#zone-feedback")).to_have_text(
        "give a reason (it is shown to every operator and kept in the audit)"
    )
    zone_form.locator("input[name=reason]").fill("cleaning")
    zone_form.locator("button[type=submit]").click()
    seen = probe.wait(topics.request("close_zone"))
    assert allowed("close_zone", parsed(seen.payload)), seen.payload
    request = decode(CloseZone, seen.payload)
    fields = json.loads(seen.payload)
    header = fields.pop("header")
    assert fields == {
        "request_id": request.request_id,
        "reply_to": dash.client_id,
        "name": "aisle-4",
        "first": [2, 1],
        "last": [4, 6],
        "reason": "cleaning",
    }
    assert set(header) == {"version", "seq", "timestamp", "sender"}
    assert header["sender"] == dash.client_id
    # One request (sent again, the same, until answered), not the one refused on the page.
    assert {m.payload for m in probe.received(topics.request("close_zone"))} == {seen.payload}
    expect(zone_form).to_be_hidden()
    expect(canvas).to_have_attribute("data-draft", "")
    coordinator_peer.reply(dash.client_id, request.request_id, True)
    expect(page.locator("#zone-feedback")).to_have_text(
        "close zone aisle-4 [2, 1] to [4, 6] (3 x 6 squares): accepted"
    )
    aisle = Zone(
        name="aisle-4",
        first=Cell(2, 1),
        last=Cell(4, 6),
        reason="cleaning",
        closed_by="dash-test",
        closed_at=datetime.now(UTC),
    )
    publish_zones(probe, topics, stamp, [DOCK, aisle])
    expect(canvas).to_have_attribute("data-zones", "dock@7,0-9,1 aisle-4@2,1-4,6")
    expect(page.locator("#zones-count")).to_have_text("(2)")
    assert zone_row(dash, "aisle-4")[:4] == [
        "aisle-4",
        "[2, 1] to [4, 6] (3 x 6 squares)",
        "cleaning",
        "dash-test",
    ]

    # Open: refused in the coordinator's words, the button back; then accepted, the zone gone.
    open_button = page.locator("#zones button[data-open='dock']")
    open_button.click()
    first = probe.wait(topics.request("open_zone"))
    assert allowed("open_zone", parsed(first.payload)), first.payload
    opened = decode(OpenZone, first.payload)
    assert (opened.name, opened.reply_to) == ("dock", dash.client_id)
    assert set(json.loads(first.payload)) == {"header", "request_id", "reply_to", "name"}
    expect(open_button).to_be_disabled()
    reason = "zone dock is not closed: the zones closed are aisle-4"
    coordinator_peer.reply(dash.client_id, opened.request_id, False, reason)
    expect(page.locator("#zones-feedback")).to_have_text(f"open zone dock: refused — {reason}")
    expect(open_button).to_be_enabled()
    open_button.click()
    again = probe.wait(topics.request("open_zone"), lambda m: m.payload != first.payload)
    coordinator_peer.reply(dash.client_id, decode(OpenZone, again.payload).request_id, True)
    expect(page.locator("#zones-feedback")).to_have_text("open zone dock: accepted")
    publish_zones(probe, topics, stamp, [aisle])
    expect(page.locator("#zones tr[data-zone]")).to_have_count(1)
    expect(canvas).to_have_attribute("data-zones", "aisle-4@2,1-4,6")

    # A zones view that breaks its schema changes nothing, and the page says so.
    broken = json.loads(ZonesView(header=stamp("zones"), zones=[aisle]).model_dump_json())
    broken["zones"][0]["first"] = [2, -1]
    probe.publish(topics.fleet("zones"), json.dumps(broken), qos=1, retain=False)
    expect(page.locator("#log")).to_contain_text("ignored a malformed zones view: zone 1 aisle-4")
    expect(canvas).to_have_attribute("data-zones", "aisle-4@2,1-4,6")
    # The hover line says a square's place and zone.
    page.mouse.move(*square_point(dash, (3, 4)))
    expect(page.locator("#hover")).to_have_text("[3, 4] · A3 (pickup) · in closed zone aisle-4")
    assert dash.errors == []


def test_a_viewer_sees_the_zones_but_no_button_to_close_or_open_one(dash: OpenDashboard) -> None:
    page = dash.page
    # The page as the dashboard serves it to an account that may not change the fleet.

    def as_viewer(route: Any) -> None:
        response = route.fetch()
        body = response.json()
        body["may_change"] = False
        route.fulfill(response=response, json=body)

    page.route("**/api/settings", as_viewer)
    page.reload()
    dash.wait_connected()
    expect(page.locator("#zones tr[data-zone='dock'] td.reason")).to_have_text("spill: wet floor")
    expect(page.locator("#map")).to_have_attribute("data-zones", "dock@7,0-9,1")
    expect(page.locator("#zones button")).to_have_count(0)
    expect(page.locator("#zone-mode")).to_be_hidden()
    expect(page.locator("#zones-hint")).to_contain_text("your account may not open or close them")
    assert dash.errors == []
