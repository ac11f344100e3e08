"""Energy on the page (issue 54), in real Chromium against the real broker: each unit's battery
beside its link, the chargers drawn on the map with the unit on each and the units queued, a
unit's energy plan in its status, and the "charge" button sending `control_unit` "charge". The
test plays the coordinator and the units; a bad battery or energy view breaks nothing."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import pytest
from playwright.sync_api import expect

from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import (
    Charger,
    ChargerView,
    ControlUnit,
    EnergyView,
    FleetMap,
    HeaderStamper,
    Leds,
    Sensors,
    Thresholds,
    Topics,
    UnitEnergy,
    UnitState,
    decode,
)
from gridfleet.scenario import load_scenario

from support.browser import OpenDashboard
from support.fleet_peer import CoordinatorPeer, UnitPeer, publish
from support.paths import MAPS
from support.probe import MqttProbe

pytestmark = pytest.mark.browser

PLAYFIELD = MAPS / "playfield.toml"
C1, C2 = Cell(0, 0), Cell(9, 0)  # free squares: unit1 and unit2 start on them
THRESHOLDS = Thresholds(critical_pct=20, good_pct=50, sufficient_pct=80, full_pct=95)
FREE = Sensors(N="free", E="free", S="free", W="free")


@pytest.fixture
def probe(probe_factory: Callable[..., MqttProbe], topics: Topics) -> MqttProbe:
    probe = probe_factory()
    probe.subscribe(topics.request("control_unit"))
    return probe


def charged_state(
    probe: MqttProbe,
    topics: Topics,
    stamp: HeaderStamper,
    unit: str,
    position: Cell,
    battery_pct: float | None,
    *,
    charging: bool = False,
) -> None:
    """`units/<unit>/state` with its battery (None: a unit that reports no energy)."""
    header = stamp("state")
    state = UnitState(
        header=header,
        step=header.seq,
        position=position,
        direction="-",
        status="idle",
        leds=Leds(),
        sensors=FREE,
        battery_pct=battery_pct,
        charging=charging,
    )
    publish(probe, "state", topics.unit("state", unit), state)


def energy_view(
    probe: MqttProbe,
    topics: Topics,
    stamp: HeaderStamper,
    chargers: Sequence[ChargerView],
    units: Mapping[str, UnitEnergy],
) -> None:
    """`fleet/energy`, as the coordinator's energy policy publishes it."""
    view = EnergyView(
        header=stamp("energy"), thresholds=THRESHOLDS, chargers=list(chargers), units=dict(units)
    )
    publish(probe, "energy", topics.fleet("energy"), view)


def energy_fleet(probe: MqttProbe, topics: Topics) -> None:
    """The playfield with two chargers; unit1 charging on C1, unit2 on its way to C2 (low),
    unit3 queued for C1 (critical), unit4 without energy."""
    grid: GridMap = load_scenario(PLAYFIELD).grid
    stamp = HeaderStamper("coordinator-energy")
    fleet_map = FleetMap(
        header=stamp("map"),
        name=grid.name,
        width=grid.width,
        height=grid.height,
        rows=grid.rows(),
        chargers=[Charger(name="C1", square=C1), Charger(name="C2", square=C2)],
    )
    publish(probe, "map", topics.fleet("map"), fleet_map)
    starts = {u.id: u for u in load_scenario(PLAYFIELD).units}
    batteries = {"unit1": 61.6, "unit2": 38.0, "unit3": 19.0, "unit4": None}
    for unit, spec in starts.items():
        peer = UnitPeer(probe, topics, unit)
        peer.connection("online")
        peer.factsheet(spec.capacity, spec.color)
        at = Cell(4, 4) if unit == "unit2" else spec.start
        charged_state(
            probe, topics, peer.stamp, unit, at, batteries[unit], charging=unit == "unit1"
        )
    energy_view(
        probe,
        topics,
        stamp,
        [
            ChargerView(name="C1", square=C1, unit="unit1", queue=["unit3"]),
            ChargerView(name="C2", square=C2, unit="unit2"),
        ],
        {
            "unit1": UnitEnergy(plan="charging", charger="C1", reason="charging: 62 % of 80 %"),
            "unit2": UnitEnergy(
                plan="to_charger", charger="C2", reason="below good 50 %; charges up to 80 %"
            ),
            "unit3": UnitEnergy(plan="queued", charger="C1"),
        },
    )


@pytest.fixture
def dash(
    open_dashboard: Callable[..., OpenDashboard],
    probe: MqttProbe,
    topics: Topics,
    coordinator: CoordinatorPeer,
) -> OpenDashboard:
    """The energy fleet on a page of the usual size."""
    energy_fleet(probe, topics)
    dash = open_dashboard()
    expect(dash.page.locator("#units-count")).to_have_text("(4)")
    return dash


@pytest.fixture
def coordinator(probe: MqttProbe, topics: Topics) -> CoordinatorPeer:
    return CoordinatorPeer(probe, topics)


def test_batteries_chargers_and_plans_are_shown(dash: OpenDashboard) -> None:
    page = dash.page
    link = page.locator("#units tr[data-unit='unit1'] .link")
    expect(link).to_have_text("62 % ⚡ · online")
    expect(link).to_have_attribute("data-battery", "62")
    expect(link).to_have_attribute("title", "battery 62 %, charging · online")
    expect(link).to_have_class("link charging")
    expect(page.locator("#units tr[data-unit='unit2'] .link")).to_have_text("38 % · online")
    # Coloured by the coordinator's thresholds (good 50 %, critical 20 %), charging or not.
    levels = {"unit1": "ok", "unit2": "low", "unit3": "critical"}
    for unit, level in levels.items():
        expect(page.locator(f"#units tr[data-unit='{unit}'] .link")).to_have_attribute(
            "data-level", level
        )
    expect(page.locator("#units tr[data-unit='unit3'] .link")).to_have_attribute(
        "title", "battery 19 %, critical (at or below 20 %) · online"
    )
    # A unit that reports no energy shows nothing new: no battery, no plan, no charge button.
    unit4 = page.locator("#units tr[data-unit='unit4']")
    expect(unit4.locator(".link")).to_have_text("online")
    expect(unit4.locator(".link")).not_to_have_attribute("data-battery", "0")
    expect(unit4.locator(".status")).to_have_text("idle")
    expect(unit4.locator("button[data-command]")).to_have_text(["pause", "out"])
    # The plans, in the status, where the unit's details are (and its card on the map).
    expect(page.locator("#units tr[data-unit='unit1'] .status")).to_have_text(
        "idle · charging: 62 % of 80 %"
    )
    expect(page.locator("#units tr[data-unit='unit2'] .status")).to_have_text(
        "idle · to charger C2: below good 50 %; charges up to 80 %"
    )
    expect(page.locator("#units tr[data-unit='unit3'] .status")).to_have_text(
        "idle · waiting for charger C1"
    )
    # The chargers on the map, each with its unit and its queue, and in words under the units.
    canvas = page.locator("#map")
    expect(canvas).to_have_attribute("data-chargers", "C1@0,0:unit1+unit3 C2@9,0:unit2")
    expect(page.locator("#chargers li")).to_have_text(
        ["C1 [0, 0]: unit1 charging · queue unit3", "C2 [9, 0]: unit2 on its way"]
    )
    expect(page.locator("#chargers")).to_be_visible()
    expect(canvas).to_have_attribute("data-units", "unit1@0,0 unit2@4,4 unit3@0,9 unit4@9,9")
    dash.screenshot("dashboard-energy")
    assert dash.errors == []


@pytest.mark.parametrize(
    "viewport",
    [{"width": 1280, "height": 800}, {"width": 1920, "height": 1080}],
    ids=lambda v: str(v["width"]),
)
def test_status_plan_and_battery_are_readable_without_hovering(
    open_dashboard: Callable[..., OpenDashboard],
    probe: MqttProbe,
    topics: Topics,
    coordinator: CoordinatorPeer,
    viewport: dict[str, int],
) -> None:
    energy_fleet(probe, topics)
    dash = open_dashboard(viewport=viewport)
    page = dash.page
    expect(page.locator("#units-count")).to_have_text("(4)")
    status = page.locator("#units tr[data-unit='unit2'] .status")
    expect(status).to_have_text("idle · to charger C2: below good 50 %; charges up to 80 %")
    expect(status).to_be_visible()
    dash.screenshot(f"dashboard-energy-{viewport['width']}")
    # No cell of any unit is cut short: its whole text is on the page, not only in its title.
    clipped = page.evaluate(
        """() => [...document.querySelectorAll('#units tbody tr[data-unit] td')]
            .filter((td) => td.scrollWidth > td.clientWidth)
            .map((td) => `${td.parentElement.dataset.unit} ${td.className}: ${td.textContent}`)"""
    )
    assert clipped == []
    # The charge button: a button of a normal size with its word, beside (not over) the status.
    charge = page.locator("#units tr[data-unit='unit2'] button[data-command=charge]")
    expect(charge).to_have_text("charge")
    expect(charge).to_be_visible()
    size = charge.evaluate("b => parseFloat(getComputedStyle(b).fontSize)")
    box, said = charge.bounding_box(), status.bounding_box()
    assert box is not None and said is not None
    assert size >= 12 and box["height"] >= 18 and box["width"] >= 44, (size, box)
    assert said["x"] + said["width"] <= box["x"], (said, box)
    # A unit at 0 %: red, and "empty" in words.
    peer = UnitPeer(probe, topics, "unit2")
    charged_state(probe, topics, peer.stamp, "unit2", Cell(4, 4), 0.0)
    link = page.locator("#units tr[data-unit='unit2'] .link")
    expect(link).to_have_text("0 % empty · online")
    expect(link).to_have_attribute("data-level", "empty")
    assert dash.errors == []


def test_the_charge_button_sends_control_unit_charge(
    dash: OpenDashboard, probe: MqttProbe, topics: Topics, coordinator: CoordinatorPeer
) -> None:
    charge = dash.page.locator("#units tr[data-unit='unit2'] button[data-command=charge]")
    expect(charge).to_have_text("charge")
    expect(charge).to_have_attribute("title", "send to charge (to full, then back to work): unit2")
    charge.click()
    request = decode(ControlUnit, probe.wait(topics.request("control_unit")).payload)
    assert (request.unit, request.command, request.reply_to) == ("unit2", "charge", dash.client_id)
    coordinator.reply(dash.client_id, request.request_id, True)
    expect(dash.page.locator("#unit-feedback")).to_have_text("send to charge unit2: accepted")
    # A refusal is said in the coordinator's words.
    dash.page.locator("#units tr[data-unit='unit3'] button[data-command=charge]").click()
    refused = decode(
        ControlUnit,
        probe.wait(
            topics.request("control_unit"),
            lambda m: decode(ControlUnit, m.payload).unit == "unit3",
            timeout=20,
        ).payload,
    )
    assert (refused.unit, refused.command) == ("unit3", "charge")
    coordinator.reply(dash.client_id, refused.request_id, False, "the map has no charger")
    expect(dash.page.locator("#unit-feedback")).to_have_text(
        "send to charge unit3: refused — the map has no charger"
    )
    assert dash.errors == []


def test_bad_energy_values_break_nothing(
    dash: OpenDashboard, probe: MqttProbe, topics: Topics
) -> None:
    page = dash.page
    # A battery out of range: the unit's row stays, its battery is left out.
    bad_state = (
        b'{"header": {"version": "1.6", "seq": 99, "timestamp": "2025-01-01T00:00:00Z", '
        b'"sender": "unit2"}, "step": 99, "position": [5, 5], "direction": "-", '
        b'"status": "idle", "battery_pct": 250, "charging": "yes"}'
    )
    probe.publish(topics.unit("state", "unit2"), bad_state, retain=True)
    expect(page.locator("#units tr[data-unit='unit2'] .pos")).to_have_text("[5, 5]")
    expect(page.locator("#units tr[data-unit='unit2'] .link")).to_have_text("online")
    # A malformed energy view: its bad parts left out, the good ones drawn.
    probe.publish(
        topics.fleet("energy"),
        b'{"chargers": [{"name": "C1", "square": [0, 0], "unit": 5}, '
        b'{"name": "C2", "square": [9, 0], "queue": ["unit3"]}], "units": {"unit1": "x"}}',
        retain=True,
    )
    expect(page.locator("#map")).to_have_attribute("data-chargers", "C1@0,0:- C2@9,0:-+unit3")
    expect(page.locator("#units tr[data-unit='unit1'] .status")).to_have_text("idle")
    expect(page.locator("#log")).to_contain_text("malformed parts of the energy view")
    probe.publish(topics.fleet("energy"), b"not json", retain=True)
    expect(page.locator("#log")).to_contain_text("malformed JSON on energy")
    expect(page.locator("#map")).to_have_attribute("data-chargers", "C1@0,0:- C2@9,0:-+unit3")
    assert dash.errors == []
