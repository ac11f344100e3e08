"""The dashboard in real Chromium against the real broker; the test plays coordinator and units
(the typed peers of tests/support/fleet_peer.py)."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import expect

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol import (
    CancelJob,
    JobView,
    RemoveUnit,
    RouteView,
    SetGoal,
    SubmitJob,
    Topics,
    decode,
    decode_estop,
)
from gridfleet.protocol.messages import JobState
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread

from support.browser import OpenDashboard, wait_in_page
from support.fleet_peer import CoordinatorPeer, UnitPeer, publish
from support.paths import MAPS
from support.probe import MqttProbe

pytestmark = pytest.mark.browser

PLAYFIELD = MAPS / "playfield.toml"
PICKUP, DROPOFF = Cell(1, 1), Cell(8, 8)  # free squares of the playfield


def job(
    job_id: str,
    state: JobState,
    unit: str | None = None,
    *,
    pickup: Cell = PICKUP,
    dropoff: Cell = DROPOFF,
    mass_kg: float = 1.5,
    reason: str | None = None,
) -> JobView:
    """A JobView with playfield squares."""
    return JobView(
        id=job_id,
        state=state,
        unit=unit,
        pickup=pickup,
        dropoff=dropoff,
        mass_kg=mass_kg,
        reason=reason,
    )


@pytest.fixture
def grid() -> GridMap:
    return load_scenario(PLAYFIELD).grid


@pytest.fixture
def probe(probe_factory: Callable[..., MqttProbe], topics: Topics) -> MqttProbe:
    """The fleet's connection: the peers publish on it, and it hears what the page sends."""
    probe = probe_factory()
    for kind in ("submit_job", "cancel_job", "set_goal"):
        probe.subscribe(topics.request(kind))
    probe.subscribe(topics.fleet("estop"))
    return probe


@pytest.fixture
def coordinator(probe: MqttProbe, topics: Topics) -> CoordinatorPeer:
    """What the coordinator publishes, played by the test."""
    return CoordinatorPeer(probe, topics)


@pytest.fixture
def units(probe: MqttProbe, topics: Topics) -> dict[str, UnitPeer]:
    """What the playfield's units publish, played by the test."""
    return {u.id: UnitPeer(probe, topics, u.id) for u in load_scenario(PLAYFIELD).units}


def playfield_fleet(
    coordinator: CoordinatorPeer, units: dict[str, UnitPeer], grid: GridMap
) -> None:
    """The map and four units at the playfield's starting squares."""
    coordinator.map(grid)
    for unit in load_scenario(PLAYFIELD).units:
        units[unit.id].connection("online")
        units[unit.id].factsheet(unit.capacity, unit.color)
        units[unit.id].state(unit.start)


@pytest.fixture
def dash(
    open_dashboard: Callable[..., OpenDashboard],
    coordinator: CoordinatorPeer,
    units: dict[str, UnitPeer],
    grid: GridMap,
    root: str,
) -> OpenDashboard:
    """The page open on the playfield, its coordinator and four units played by peers."""
    playfield_fleet(coordinator, units, grid)
    dash = open_dashboard()
    # Shown before the test acts: what arrives after would change the page under its clicks.
    expect(dash.page.locator("#map-name")).to_have_text("playfield 10 x 10")
    expect(dash.page.locator("#units-count")).to_have_text("(4)")
    return dash


def row(dash: OpenDashboard, unit: str) -> Any:
    return dash.page.locator(f"#units tr[data-unit='{unit}']")


def test_units_appear_at_their_positions_and_move(
    dash: OpenDashboard,
    probe: MqttProbe,
    units: dict[str, UnitPeer],
    topics: Topics,
) -> None:
    page = dash.page
    expect(page.locator("#map-name")).to_have_text("playfield 10 x 10")
    expect(row(dash, "unit1").locator(".pos")).to_have_text("[0, 0]")
    expect(row(dash, "unit4").locator(".pos")).to_have_text("[9, 9]")
    expect(page.locator("#map")).to_have_attribute(
        "data-units", "unit1@0,0 unit2@9,0 unit3@0,9 unit4@9,9"
    )
    expect(row(dash, "unit1").locator(".link")).to_have_text("online")
    expect(row(dash, "unit2").locator(".load")).to_have_text("0/5 kg")

    units["unit1"].state(Cell(1, 0), Direction.E, "moving", job_id="job-1", load_kg=1.5)
    expect(row(dash, "unit1").locator(".pos")).to_have_text("[1, 0]")
    expect(row(dash, "unit1").locator(".status")).to_have_text("moving")
    expect(row(dash, "unit1").locator(".job")).to_have_text("job-1")
    expect(row(dash, "unit1").locator(".load")).to_have_text("1.5/2 kg")
    expect(page.locator("#map")).to_have_attribute(
        "data-units", "unit1@1,0 unit2@9,0 unit3@0,9 unit4@9,9"
    )
    assert dash.drawn_units()["unit1"] == (1, 0)
    units["unit2"].state(Cell(9, 1), Direction.S, "waiting", obstacles=[Cell(7, 2)])
    expect(page.locator("#map")).to_have_attribute("data-obstacles", "7,2*")
    units["unit3"].connection("broken")
    expect(row(dash, "unit3").locator(".link")).to_have_text("broken")

    # Garbage on the topics it reads is ignored; the page keeps working.
    probe.publish(topics.unit("state", "unit2"), b"{not json", qos=0)
    probe.publish(topics.fleet("estop"), b"maybe|x|y", qos=1)
    units["unit2"].state(Cell(8, 0), Direction.W, "moving")
    units["unit1"].state(Cell(1, 0), Direction.E, "moving", job_id="job-1", load_kg=1.5)
    expect(row(dash, "unit2").locator(".pos")).to_have_text("[8, 0]")
    expect(page.locator("body")).not_to_have_attribute("data-estop", "engaged")
    expect(page.locator("#log")).to_contain_text("malformed JSON")

    # The map scales with the window.
    big = float(page.locator("#map").get_attribute("data-cell") or 0)
    page.set_viewport_size({"width": 900, "height": 600})
    expect(page.locator("#map")).not_to_have_attribute("data-cell", str(int(big)))
    assert 0 < float(page.locator("#map").get_attribute("data-cell") or 0) < big

    # A reload recovers the full view from retained messages alone.
    page.reload()
    dash.wait_connected()
    expect(row(dash, "unit1").locator(".pos")).to_have_text("[1, 0]")
    expect(row(dash, "unit3").locator(".link")).to_have_text("broken")
    assert dash.errors == []


def test_live_playfield_screenshot(
    open_dashboard: Callable[..., OpenDashboard],
    coordinator: CoordinatorPeer,
    units: dict[str, UnitPeer],
    grid: GridMap,
) -> None:
    coordinator.map(grid, obstacles=[Cell(4, 5)])
    for unit in load_scenario(PLAYFIELD).units:
        units[unit.id].connection("online")
        units[unit.id].factsheet(unit.capacity, unit.color)
    units["unit1"].state(Cell(3, 1), Direction.E, "moving", job_id="job-1", load_kg=1.5)
    units["unit2"].state(Cell(8, 2), Direction.S, "moving")
    units["unit3"].state(Cell(1, 8), Direction.N, "moving")
    units["unit4"].state(
        Cell(4, 4), None, "waiting", wait_reason="released square [4, 5] is blocked"
    )
    coordinator.routes(
        {
            "unit1": RouteView(
                released=[(4, 1)], planned=[(5, 1), (6, 1), (7, 1), (8, 1)], target=(8, 1)
            ),
            "unit2": RouteView(
                released=[(8, 3)], planned=[(8, 4), (8, 5), (8, 6), (8, 7), (8, 8)], target=(8, 8)
            ),
            "unit3": RouteView(released=[(1, 7)], planned=[(1, 6), (1, 5), (0, 5)], target=(0, 5)),
            "unit4": RouteView(),
        }
    )
    coordinator.jobs(
        [
            job("job-1", "to_dropoff", "unit1", pickup=Cell(1, 1), dropoff=Cell(8, 1)),
            job("job-2", "to_pickup", "unit2", pickup=Cell(8, 8), dropoff=Cell(1, 8), mass_kg=4.0),
            job("job-3", "to_pickup", "unit3", pickup=Cell(0, 5), dropoff=Cell(5, 9), mass_kg=8.0),
            job("job-4", "queued", None, pickup=Cell(5, 0), dropoff=Cell(9, 5), mass_kg=15.0),
            job("job-0", "done", "unit4", pickup=Cell(2, 0), dropoff=Cell(9, 2)),
            job(
                "job-9",
                "rejected",
                None,
                mass_kg=50.0,
                reason="mass 50.0 kg exceeds every unit's capacity (largest 20.0 kg)",
            ),
        ]
    )
    coordinator.status("online", step=42, step_period_s=1.0)
    dash = open_dashboard()
    expect(dash.page.locator("#map")).to_have_attribute(
        "data-units", "unit1@3,1 unit2@8,2 unit3@1,8 unit4@4,4"
    )
    expect(dash.page.locator("#coord")).to_have_text("coordinator: online, step 42")
    # Found before the page loaded: drawn as an obstacle, not flashing as new.
    expect(dash.page.locator("#map")).to_have_attribute("data-obstacles", "4,5")
    expect(dash.page.locator("#jobs tbody tr")).to_have_count(4)
    expect(dash.page.locator("#finished-counts")).to_have_text("done 1 · rejected 1")
    shot = dash.screenshot("dashboard-playfield")
    assert shot.stat().st_size > 10_000


def test_submit_job_through_the_form(
    dash: OpenDashboard,
    probe: MqttProbe,
    coordinator: CoordinatorPeer,
    topics: Topics,
) -> None:
    dash.submit_job((1, 1), (8, 8), 1.5)

    seen = probe.wait(topics.request("submit_job"))
    request = decode(SubmitJob, seen.payload)
    assert (request.pickup, request.dropoff, request.mass_kg) == ((1, 1), (8, 8), 1.5)
    assert request.reply_to == dash.client_id and request.header.sender == dash.client_id
    assert request.priority == 0 and request.job_id is None

    coordinator.reply(dash.client_id, request.request_id, True)
    expect(dash.page.locator("#job-feedback")).to_contain_text("accepted")
    coordinator.jobs([job("job-1", "queued")])
    queued = dash.page.locator("#jobs tr[data-job='job-1']")
    expect(queued.locator(".state")).to_have_text("queued")
    coordinator.jobs([job("job-1", "to_pickup", "unit1")])
    expect(queued.locator(".unit")).to_have_text("unit1")
    coordinator.jobs([job("job-1", "done", "unit1")])
    expect(dash.page.locator("#finished tr[data-job='job-1'] .state")).to_have_text("done")
    expect(dash.page.locator("#jobs tbody tr")).to_have_count(0)
    expect(dash.page.locator("#finished-counts")).to_have_text("done 1")


def test_the_click_modes_stay_put_whatever_the_maps_name(
    open_dashboard: Callable[..., OpenDashboard], coordinator: CoordinatorPeer, grid: GridMap
) -> None:
    # A click on "click picks job squares" as the map's name arrived beside it missed (a CI run).
    dash = open_dashboard()
    choice = dash.page.locator("input[name=clickmode][value=job]")
    before = choice.bounding_box()
    coordinator.map(grid)
    expect(dash.page.locator("#map-name")).to_have_text("playfield 10 x 10")
    assert choice.bounding_box() == before
    long_name = "the north hall, bays 1 to 40, with the loading docks " * 2
    coordinator.map(GridMap.from_rows(["...", "..."], name=long_name))
    expect(dash.page.locator("#map-name")).to_have_attribute("title", re.compile("north hall"))
    assert choice.bounding_box() == before


def test_queue_job_by_clicking_two_squares(
    dash: OpenDashboard,
    probe: MqttProbe,
    topics: Topics,
) -> None:
    dash.page.locator("input[name=clickmode][value=job]").check()
    dash.click_square(5, 0)
    dash.click_square(5, 9)
    dash.page.locator("#job-form input[name=mass]").fill("8")
    dash.page.locator("#job-form button[type=submit]").click()
    request = decode(SubmitJob, probe.wait(topics.request("submit_job")).payload)
    assert (request.pickup, request.dropoff, request.mass_kg) == ((5, 0), (5, 9), 8.0)


def test_form_refuses_a_square_off_the_map_without_sending(
    dash: OpenDashboard,
    probe: MqttProbe,
    topics: Topics,
) -> None:
    form = dash.page.locator("#job-form")
    for name, value in (("pickup", "12,1"), ("dropoff", "8,8")):
        form.locator(f"input[name={name}]").fill(value)
    form.locator("button[type=submit]").click()
    expect(dash.page.locator("#job-feedback")).to_have_text(
        "pickup [12,1] is not a square of the map"
    )
    # A valid one afterwards is the first and only request on the topic.
    form.locator("input[name=pickup]").fill("2,1")
    form.locator("button[type=submit]").click()
    probe.wait(topics.request("submit_job"))
    assert [
        decode(SubmitJob, m.payload).pickup for m in probe.received(topics.request("submit_job"))
    ] == [(2, 1)]


def test_rejection_is_shown_in_words(
    dash: OpenDashboard,
    probe: MqttProbe,
    coordinator: CoordinatorPeer,
    topics: Topics,
) -> None:
    form = dash.page.locator("#job-form")
    for name, value in (("pickup", "0,5"), ("dropoff", "9,5"), ("mass", "50")):
        form.locator(f"input[name={name}]").fill(value)
    form.locator("button[type=submit]").click()
    request = decode(SubmitJob, probe.wait(topics.request("submit_job")).payload)
    reason = "mass 50.0 kg exceeds every unit's capacity (largest 20.0 kg)"
    coordinator.reply(dash.client_id, request.request_id, False, reason)
    feedback = dash.page.locator("#job-feedback")
    expect(feedback).to_contain_text(f"refused — {reason}")
    expect(feedback).to_have_attribute("data-kind", "refused")

    # A refusal that comes only on `errors` (with our request id) is shown the same way.
    dash.set_goal("unit2", (2, 2))
    goal = decode(SetGoal, probe.wait(topics.request("set_goal")).payload)
    coordinator.error(topics.request("set_goal"), "target [2, 2] is a wall", goal.request_id)
    expect(dash.page.locator("#goal-feedback")).to_contain_text("refused — target [2, 2] is a wall")


def test_delete_publishes_cancel_job(
    open_dashboard: Callable[..., OpenDashboard],
    probe: MqttProbe,
    coordinator: CoordinatorPeer,
    units: dict[str, UnitPeer],
    grid: GridMap,
    topics: Topics,
) -> None:
    playfield_fleet(coordinator, units, grid)
    coordinator.jobs([job("job-3", "queued"), job("job-4", "to_pickup", "unit2")])
    dash = open_dashboard()
    dash.cancel_job("job-4")
    request = decode(CancelJob, probe.wait(topics.request("cancel_job")).payload)
    assert request.job_id == "job-4" and request.reply_to == dash.client_id
    coordinator.reply(dash.client_id, request.request_id, True)
    expect(dash.page.locator("#cancel-feedback")).to_contain_text("delete job job-4: accepted")
    coordinator.jobs(
        [job("job-3", "queued"), job("job-4", "cancelled", "unit2", reason="cancelled by operator")]
    )
    expect(dash.page.locator("#finished tr[data-job='job-4'] .state")).to_have_text("cancelled")
    expect(dash.page.locator("#jobs tbody tr")).to_have_count(1)


def test_set_goal_by_clicking_the_map(
    dash: OpenDashboard,
    probe: MqttProbe,
    units: dict[str, UnitPeer],
    topics: Topics,
) -> None:
    dash.page.locator("input[name=clickmode][value=goal]").check()
    dash.click_square(9, 0)  # clicking a unit chooses it
    expect(dash.page.locator("#units tr.selected")).to_have_attribute("data-unit", "unit2")
    dash.click_square(9, 3)
    request = decode(SetGoal, probe.wait(topics.request("set_goal")).payload)
    assert (request.unit, request.target, request.reply_to) == ("unit2", (9, 3), dash.client_id)
    dash.page.locator("#goal-clear").click()
    cleared = probe.wait(
        topics.request("set_goal"), lambda m: decode(SetGoal, m.payload).target is None
    )
    assert decode(SetGoal, cleared.payload).unit == "unit2"


def test_stop_button_engages_and_hold_releases(
    dash: OpenDashboard,
    broker: BrokerThread,
    probe: MqttProbe,
    topics: Topics,
) -> None:
    page = dash.page
    estop_topic = topics.fleet("estop")
    expect(page.locator("#release")).to_be_hidden()
    stop_box = page.locator("#stop").bounding_box()
    page.locator("#stop").click()
    seen = probe.wait(estop_topic, lambda m: decode_estop(m.payload).engaged)
    signal = decode_estop(seen.payload)
    page_id = page.evaluate("document.body.dataset.clientId")
    assert signal.by == page_id and seen.qos == 1  # the page's own id: its account owns it
    # Retained: a newcomer learns the stop from the broker.
    late = MqttProbe(broker.url).connect()
    try:
        late.subscribe(estop_topic)
        assert decode_estop(late.wait(estop_topic).payload).engaged
    finally:
        late.close()
    expect(page.locator("body")).to_have_attribute("data-estop", "engaged")
    expect(page.locator("#estop-banner")).to_contain_text(f"EMERGENCY STOP — engaged by {page_id}")
    # The banner changes the layout; the map is redrawn to fit its box again.
    wait_in_page(
        page,
        """() => {
            const c = document.querySelector('#map'), box = c.parentElement.getBoundingClientRect();
            return Number(c.dataset.oy) + 10 * Number(c.dataset.cell) <= box.height;
        }""",
    )
    dash.screenshot("dashboard-stopped")
    # STOP stays under the finger that pressed it, and neither button moves as the status beside
    # them grows: a held release was cancelled when "hold to release" slid from under the pointer.
    release = page.locator("#release")
    release_box = release.bounding_box()
    assert page.locator("#stop").bounding_box() == stop_box
    page.evaluate(
        "document.querySelector('#coord').textContent += ' · 250 ms a step (set 100 ms) · more'"
    )
    assert (page.locator("#stop").bounding_box(), release.bounding_box()) == (stop_box, release_box)

    # A short press does not release; holding for 1.5 s does.
    release.hover()
    page.mouse.down()
    page.mouse.up()
    dash.hold_release()
    probe.wait(estop_topic, lambda m: not decode_estop(m.payload).engaged, timeout=5)
    releases = [m for m in probe.received(estop_topic) if not decode_estop(m.payload).engaged]
    assert len(releases) == 1 and decode_estop(releases[0].payload).by == page_id
    expect(page.locator("body")).to_have_attribute("data-estop", "released")
    expect(page.locator("#estop-banner")).to_be_hidden()


def test_estop_engaged_elsewhere_is_shown(
    dash: OpenDashboard,
    probe: MqttProbe,
    topics: Topics,
) -> None:
    publish(probe, "estop", topics.fleet("estop"), b"engaged|device1|button pressed")
    expect(dash.page.locator("body")).to_have_attribute("data-estop", "engaged")
    expect(dash.page.locator("#estop-banner")).to_have_text(
        "EMERGENCY STOP — engaged by device1: button pressed"
    )
    dash.page.reload()
    dash.wait_connected()
    expect(dash.page.locator("#estop-banner")).to_contain_text("engaged by device1")
    publish(probe, "estop", topics.fleet("estop"), b"released|operator|checked")
    expect(dash.page.locator("body")).to_have_attribute("data-estop", "released")


@pytest.mark.every_broker  # a broker restarted, over websockets
def test_reconnects_after_broker_restart(
    open_dashboard: Callable[..., OpenDashboard],
    fresh_broker: BrokerThread,
    grid: GridMap,
    topics: Topics,
) -> None:
    with MqttProbe(fresh_broker.url) as probe:
        CoordinatorPeer(probe, topics).map(grid)
        UnitPeer(probe, topics, "unit1").state(Cell(0, 0))
    dash = open_dashboard(via=fresh_broker)
    expect(row(dash, "unit1").locator(".pos")).to_have_text("[0, 0]")
    fresh_broker.restart()
    with MqttProbe(fresh_broker.url) as probe:
        probe.subscribe(topics.fleet("estop"))
        dash.wait_connected()  # same page, no reload: reconnected and subscribed again
        UnitPeer(probe, topics, "unit1").state(Cell(1, 0), Direction.E, "moving")
        expect(row(dash, "unit1").locator(".pos")).to_have_text("[1, 0]")
        dash.page.locator("#stop").click()
        assert decode_estop(probe.wait(topics.fleet("estop")).payload).engaged
    assert dash.errors == []


def test_missing_mqtt_js_says_how_to_install(
    open_dashboard: Callable[..., OpenDashboard], tmp_path: Path
) -> None:
    dash = open_dashboard(wait_connected=False, node_modules=tmp_path)
    expect(dash.page.locator("#fatal")).to_contain_text("run 'npm ci' in the dashboard/ folder")
    expect(dash.page.locator("#conn")).to_have_attribute("data-state", "failed")


@pytest.mark.every_broker  # a broker restarted, over websockets
def test_stop_pressed_while_broker_is_down_is_sent_when_it_returns(
    open_dashboard: Callable[..., OpenDashboard],
    fresh_broker: BrokerThread,
    grid: GridMap,
    topics: Topics,
) -> None:
    dash = open_dashboard(via=fresh_broker, grid=grid)
    fresh_broker.stop()
    expect(dash.page.locator("#conn")).not_to_have_attribute("data-state", "connected")
    dash.page.locator("#stop").click()
    # The page shows the stop at once, even before any broker has it.
    expect(dash.page.locator("body")).to_have_attribute("data-estop", "engaged")
    expect(dash.page.locator("#estop-banner")).to_contain_text("sending")
    fresh_broker.start()
    dash.wait_connected()
    with MqttProbe(fresh_broker.url) as probe:
        probe.subscribe(topics.fleet("estop"))  # retained: it arrived while we were away
        assert decode_estop(probe.wait(topics.fleet("estop")).payload).engaged
    page_id = dash.page.evaluate("document.body.dataset.clientId")
    expect(dash.page.locator("#estop-banner")).to_contain_text(f"engaged by {page_id}")


def test_rows_survive_renders_so_clicks_are_not_lost(
    open_dashboard: Callable[..., OpenDashboard],
    coordinator: CoordinatorPeer,
    units: dict[str, UnitPeer],
    grid: GridMap,
) -> None:
    # Found against the real fleet: rows were rebuilt on every message (units report every
    # step), so the "delete" button under the pointer was replaced and the click was lost.
    playfield_fleet(coordinator, units, grid)
    coordinator.jobs([job("job-3", "queued")])
    dash = open_dashboard()
    button = dash.page.locator("#jobs button[data-cancel='job-3']")
    expect(button).to_be_visible()
    kept_button = button.element_handle()
    kept_row = row(dash, "unit1").element_handle()
    units["unit1"].state(Cell(1, 0), Direction.E, "moving")
    expect(row(dash, "unit1").locator(".pos")).to_have_text("[1, 0]")
    coordinator.jobs([job("job-3", "to_pickup", "unit2"), job("job-4", "queued")])
    expect(dash.page.locator("#jobs tr[data-job='job-3'] .unit")).to_have_text("unit2")
    expect(dash.page.locator("#jobs tbody tr")).to_have_count(2)
    assert kept_button.evaluate("b => b.isConnected")
    assert kept_row.evaluate("tr => tr.isConnected")
    # Finished jobs leave the queue; the rest keep their rows.
    coordinator.jobs([job("job-3", "done", "unit2"), job("job-4", "queued")])
    expect(dash.page.locator("#finished tr[data-job='job-3'] .state")).to_have_text("done")
    expect(dash.page.locator("#jobs tbody tr")).to_have_count(1)
    assert not kept_button.evaluate("b => b.isConnected")
    assert dash.errors == []


def test_a_lost_unit_is_removed_from_its_row_after_a_confirmation(
    dash: OpenDashboard,
    probe: MqttProbe,
    coordinator: CoordinatorPeer,
    units: dict[str, UnitPeer],
    topics: Topics,
) -> None:
    # Only a lost unit offers "remove"; the page asks first, and a "no" sends nothing.
    expect(row(dash, "unit2").locator("button[data-remove]")).to_have_count(0)
    units["unit2"].connection("broken")
    remove = row(dash, "unit2").locator("button[data-remove=unit2]")
    expect(remove).to_have_text("remove")
    request_topic = topics.request("remove_unit")
    probe.subscribe(request_topic)
    asked: list[str] = []

    def answer(dialog: Any) -> None:
        asked.append(dialog.message)
        if len(asked) == 1:
            dialog.dismiss()
        else:
            dialog.accept()

    dash.page.on("dialog", answer)
    remove.click()
    remove.click()
    request = decode(RemoveUnit, probe.wait(request_topic).payload)
    assert (request.unit, request.reply_to) == ("unit2", dash.client_id)
    assert len(asked) == 2 and asked[0].startswith("Remove unit2 for good?")
    sent = {decode(RemoveUnit, m.payload).request_id for m in probe.received(request_topic)}
    assert sent == {request.request_id}  # the first, dismissed, sent nothing (retries: the same)
    said = "unit unit2 removed; it had no job"
    coordinator.reply(dash.client_id, request.request_id, True, said)
    expect(dash.page.locator("#unit-feedback")).to_have_text(f"remove unit2: accepted — {said}")
    for kind in ("state", "factsheet", "vehicle", "connection"):  # as it clears them
        probe.publish(topics.unit(kind, "unit2"), b"", retain=True)
    expect(row(dash, "unit2")).to_have_count(0)
    expect(dash.page.locator("#units-count")).to_have_text("(3)")
