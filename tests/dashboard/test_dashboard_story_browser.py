"""The dashboard tells the fleet's story (issue 14, finding 8): each unit's job and load, paired
pickups and dropoffs, finished jobs with durations, an event log that survives a reload, what is
new, labels apart, zoom and pan, a throughput chart, why jobs wait, and per-unit control. Real
Chromium against the real broker; the test plays coordinator and units."""

from __future__ import annotations

import json
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import expect

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol import ControlUnit, EventEntry, JobView, RouteView, Topics, decode
from gridfleet.protocol.messages import JobState
from gridfleet.scenario import load_scenario

from support.browser import OpenDashboard, wait_in_page
from support.fleet_peer import CoordinatorPeer, UnitPeer
from support.paths import MAPS
from support.probe import MqttProbe

pytestmark = pytest.mark.browser

PLAYFIELD = MAPS / "playfield.toml"
WAREHOUSE = MAPS / "warehouse.toml"
PICKUP, DROPOFF = Cell(1, 1), Cell(8, 8)


def job(
    job_id: str,
    state: JobState,
    unit: str | None = None,
    pickup: Cell = PICKUP,
    dropoff: Cell = DROPOFF,
    **more: Any,
) -> JobView:
    """A playfield job."""
    return JobView(
        id=job_id, state=state, unit=unit, pickup=pickup, dropoff=dropoff, mass_kg=1.5, **more
    )


@pytest.fixture
def probe(probe_factory: Callable[..., MqttProbe], topics: Topics) -> MqttProbe:
    probe = probe_factory()
    probe.subscribe(topics.request("control_unit"))
    return probe


@pytest.fixture
def coordinator(probe: MqttProbe, topics: Topics) -> CoordinatorPeer:
    return CoordinatorPeer(probe, topics)


@pytest.fixture
def fleet_of(
    probe: MqttProbe, topics: Topics, coordinator: CoordinatorPeer
) -> Callable[[Path], dict[str, UnitPeer]]:
    """Factory: a scenario's map, and its units online at their starts, played by peers."""

    def publish(scenario: Path) -> dict[str, UnitPeer]:
        loaded = load_scenario(scenario)
        coordinator.map(loaded.grid)
        units = {}
        for unit in loaded.units:
            peer = units[unit.id] = UnitPeer(probe, topics, unit.id)
            peer.connection("online")
            peer.factsheet(unit.capacity, unit.color)
            peer.state(unit.start)
        return units

    return publish


def row(dash: OpenDashboard, unit: str) -> Any:
    return dash.page.locator(f"#units tr[data-unit='{unit}']")


def until(dash: OpenDashboard, attribute: str, test: str) -> str:
    """Wait until the map's data attribute `attribute`, as `v`, passes the JS test; its value."""
    wait_in_page(
        dash.page,
        f"(() => {{ const v = document.querySelector('#map').dataset.{attribute}; "
        f"return v !== undefined && ({test}); }})()",
    )
    return str(dash.page.locator("#map").get_attribute(f"data-{attribute}"))


def test_each_unit_shows_its_job_before_pickup_and_what_it_carries(
    open_dashboard: Callable[..., OpenDashboard],
    fleet_of: Callable[[Path], dict[str, UnitPeer]],
    coordinator: CoordinatorPeer,
) -> None:
    units = fleet_of(PLAYFIELD)
    units["unit1"].state(Cell(3, 1), Direction.E, "moving", job_id="job-1", load_kg=1.5)
    coordinator.jobs(
        [
            job("job-1", "to_dropoff", "unit1", dropoff=Cell(8, 1)),
            job("job-2", "to_pickup", "unit2", pickup=Cell(8, 8), dropoff=Cell(1, 8)),
            job("job-3", "queued", None, pickup=Cell(5, 0), dropoff=Cell(9, 5)),
        ]
    )
    dash = open_dashboard()
    # Before pickup the unit's own state names no job; the queue does.
    expect(row(dash, "unit2").locator(".job")).to_have_text("job-2")
    expect(row(dash, "unit1").locator(".job")).to_have_text("job-1")
    expect(row(dash, "unit1").locator(".job")).to_have_class("job carrying")
    canvas = dash.page.locator("#map")
    expect(canvas).to_have_attribute("data-carrying", "unit1:job-1")
    # Numbered pairs: a carried job shows only its dropoff.
    number = {
        j: dash.page.locator(f"#jobs tr[data-job='{j}'] .no").inner_text()
        for j in ("job-1", "job-2", "job-3")
    }
    expected = sorted(
        [
            f"D{number['job-1']}@8,1",
            f"P{number['job-2']}@8,8",
            f"D{number['job-2']}@1,8",
            f"P{number['job-3']}@5,0",
            f"D{number['job-3']}@9,5",
        ]
    )
    expect(canvas).to_have_attribute("data-markers", " ".join(expected))
    dash.page.locator("#jobs tr[data-job='job-2'] .id").click()
    expect(dash.page.locator("#jobs tr[data-job='job-2']")).to_have_class("job-to_pickup selected")
    assert dash.errors == []


def test_finished_jobs_newest_first_bounded_with_how_long_they_took(
    open_dashboard: Callable[..., OpenDashboard],
    fleet_of: Callable[[Path], dict[str, UnitPeer]],
    coordinator: CoordinatorPeer,
) -> None:
    fleet_of(PLAYFIELD)
    coordinator.status("online", step=1000, step_period_s=0.1)
    done = [
        job(f"j{i:02d}", "done", "unit1", created_step=10 * i, done_step=10 * i + 125)
        for i in range(25)
    ]
    coordinator.jobs(done)
    dash = open_dashboard()
    rows = dash.page.locator("#finished tbody tr")
    expect(rows).to_have_count(20)
    expect(rows.first).to_have_attribute("data-job", "j24")
    expect(rows.first.locator(".took")).to_have_text("12.5 s")
    expect(dash.page.locator("#finished-counts")).to_have_text("done 25")


def test_the_event_log_is_the_coordinators_and_survives_a_reload(
    open_dashboard: Callable[..., OpenDashboard],
    fleet_of: Callable[[Path], dict[str, UnitPeer]],
    coordinator: CoordinatorPeer,
) -> None:
    fleet_of(PLAYFIELD)
    at = datetime(2026, 11, 24, 9, 5, 7, tzinfo=UTC)
    coordinator.events(
        [
            EventEntry(at=at, kind="job", text="job crate queued by dashboard", job="crate"),
            EventEntry(at=at, kind="stop", text="emergency stop ENGAGED by operator: drill"),
            EventEntry(at=at, kind="job", text="job crate done by unit2 in 14.2 s", job="crate"),
        ]
    )
    dash = open_dashboard()
    lines = dash.page.locator("#events li")
    expect(lines).to_have_count(3)
    expect(lines.first).to_contain_text("job crate done by unit2 in 14.2 s")
    local = at.astimezone().strftime("%H:%M:%S")  # the page shows the browser's local time
    expect(lines.first.locator("time")).to_have_text(local)
    dash.page.reload()
    dash.wait_connected()
    expect(lines).to_have_count(3)
    expect(lines.nth(1)).to_have_class("event-stop")


def test_only_obstacles_found_since_the_page_loaded_are_new(
    open_dashboard: Callable[..., OpenDashboard],
    fleet_of: Callable[[Path], dict[str, UnitPeer]],
    coordinator: CoordinatorPeer,
) -> None:
    units = fleet_of(PLAYFIELD)
    coordinator.map(load_scenario(PLAYFIELD).grid, obstacles=[Cell(4, 5)])
    dash = open_dashboard()
    canvas = dash.page.locator("#map")
    expect(canvas).to_have_attribute("data-obstacles", "4,5")
    units["unit2"].state(Cell(9, 1), Direction.S, "waiting", obstacles=[Cell(7, 2)])
    expect(canvas).to_have_attribute("data-obstacles", "4,5 7,2*")


def test_an_answer_goes_when_the_form_is_edited_again(
    open_dashboard: Callable[..., OpenDashboard],
    fleet_of: Callable[[Path], dict[str, UnitPeer]],
) -> None:
    fleet_of(PLAYFIELD)
    dash = open_dashboard()
    dash.submit_job((1, 1), (99, 99), 1.0)
    feedback = dash.page.locator("#job-feedback")
    expect(feedback).to_contain_text("is not a square of the map")
    dash.page.locator("#job-form input[name=dropoff]").fill("8,8")
    expect(feedback).to_have_text("")


def _overlaps(a: list[int], b: list[int]) -> bool:
    ax, ay, aw, ah = a
    bx, by, bw, bh = b
    return ax < bx + bw and bx < ax + aw and ay < by + bh and by < ay + ah


def test_unit_names_never_overlap_at_1280_by_720(
    open_dashboard: Callable[..., OpenDashboard],
    fleet_of: Callable[[Path], dict[str, UnitPeer]],
) -> None:
    # The warehouse's twelve units start side by side in one row: the names used to run together.
    fleet_of(WAREHOUSE)
    dash = open_dashboard()
    dash.page.set_viewport_size({"width": 1280, "height": 720})
    until(dash, "units", "v.split(' ').length === 12")
    labels = json.loads(until(dash, "labels", "JSON.parse(v).length > 0"))
    boxes = [box for _, *box in labels]
    assert len(labels) >= 6, labels
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not _overlaps(a, b), (a, b)


def _big_map(width: int = 500, height: int = 140) -> GridMap:
    rows = ["." * width if y % 10 else "." + "@" * (width - 2) + "." for y in range(height)]
    return GridMap.from_rows(rows, name="big")


def test_a_map_larger_than_the_view_zooms_and_pans(
    open_dashboard: Callable[..., OpenDashboard],
    coordinator: CoordinatorPeer,
) -> None:
    coordinator.map(_big_map())
    dash = open_dashboard()
    canvas = dash.page.locator("#map")
    whole = float(until(dash, "cell", "+v > 0 && +v < 2"))
    box = canvas.bounding_box()
    assert box is not None
    assert whole * 500 <= box["width"] + 1, "the whole map fits"
    centre = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    dash.page.mouse.move(*centre)
    for _ in range(8):
        dash.page.mouse.wheel(0, -100)
    until(dash, "cell", f"+v > {5 * whole}")
    ox = float(canvas.get_attribute("data-ox") or 0)
    dash.page.mouse.down()
    dash.page.mouse.move(centre[0] + 150, centre[1], steps=5)
    dash.page.mouse.up()
    until(dash, "ox", f"+v > {ox + 100}")
    dash.page.locator("#fit").click()
    expect(canvas).to_have_attribute("data-cell", str(+round(whole, 2)))


def test_the_chart_counts_jobs_done_a_minute_and_how_busy_units_are(
    open_dashboard: Callable[..., OpenDashboard],
    fleet_of: Callable[[Path], dict[str, UnitPeer]],
    coordinator: CoordinatorPeer,
) -> None:
    units = fleet_of(PLAYFIELD)
    units["unit1"].state(Cell(3, 1), Direction.E, "moving", job_id="job-9", load_kg=1.5)
    coordinator.status("online", step=6000, step_period_s=0.1)
    coordinator.jobs(
        [
            job("a", "done", "unit1", created_step=0, done_step=5999),
            job("b", "done", "unit1", created_step=0, done_step=5500),
            job("c", "done", "unit2", created_step=0, done_step=5000),
            job("job-9", "to_dropoff", "unit1"),
        ],
        done_per_minute=[0, 0, 0, 0, 0, 0, 0, 0, 1, 2],  # the coordinator counts them
    )
    dash = open_dashboard()
    chart = dash.page.locator("#chart")
    expect(chart).to_have_attribute("data-per-minute", "0 0 0 0 0 0 0 0 1 2")
    expect(chart).to_have_attribute("data-utilisation", "0.25")  # 1 of 4 units online has work
    # Labelled (the hour-long demo: no axis, a line without a value, an all-zero empty box).
    expect(chart).to_have_attribute("data-busy", "25 % of units busy")
    expect(chart).to_have_attribute("data-note", "")
    coordinator.jobs([job("job-9", "to_dropoff", "unit1")])  # nothing done any more
    expect(chart).to_have_attribute("data-note", "no job done in the last 10 min")


def test_unit_rows_pause_and_take_out_of_service_and_jobs_say_why_they_wait(
    open_dashboard: Callable[..., OpenDashboard],
    fleet_of: Callable[[Path], dict[str, UnitPeer]],
    probe: MqttProbe,
    topics: Topics,
    coordinator: CoordinatorPeer,
) -> None:
    fleet_of(PLAYFIELD)
    reason = "every unit that can carry 1.5 kg is busy (unit1, unit3)"
    coordinator.jobs([job("job-5", "queued", None, wait="no_unit_free", wait_reason=reason)])
    dash = open_dashboard()
    queued = dash.page.locator("#jobs tr[data-job='job-5']")
    expect(queued.locator(".state")).to_have_text("queued")
    expect(queued.locator(".waits")).to_have_text(reason)
    row(dash, "unit2").locator("button[data-command=out_of_service]").click()
    request = decode(ControlUnit, probe.wait(topics.request("control_unit")).payload)
    assert (request.unit, request.command, request.reply_to) == (
        "unit2",
        "out_of_service",
        dash.client_id,
    )
    coordinator.reply(dash.client_id, request.request_id, True)
    expect(dash.page.locator("#unit-feedback")).to_have_text("take out of service unit2: accepted")
    coordinator.routes({"unit2": RouteView(control="out_of_service")})
    expect(row(dash, "unit2").locator(".status")).to_have_text("out of service · idle")
    expect(row(dash, "unit2").locator("button[data-command]")).to_have_text(["in service"])
    # A unit that says "idle" while its job is stuck shows what holds the job (the hour-long
    # demo: loaded units jammed for 21 minutes read "idle" with no reason).
    stuck = "its unit unit1 has not moved for over 5 min at [0, 0]; unit3 stands where it must go"
    coordinator.jobs(
        [
            job("job-5", "queued", None, wait="no_unit_free", wait_reason=reason),
            job("job-6", "to_pickup", "unit1", wait="unit_stuck", wait_reason=stuck),
        ]
    )
    expect(row(dash, "unit1").locator(".status")).to_have_text(f"idle · {stuck}")
    assert dash.errors == []
