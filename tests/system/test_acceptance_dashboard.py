"""Acceptance items 3, 8 and 9 (the course manual's Appendix A): the dashboard in Chromium on the REAL system.

Real broker, real coordinator, real simulated units (threads, `run_system`) and the page in headless
Chromium: nothing between them is faked. The world simulation (`world_of`) is the ground truth the
page is checked against; a probe only listens.

`GRIDFLEET_REFRESH_DOCS=1 .venv/bin/pytest tests/system/test_acceptance_dashboard.py -k screenshot` also
copies the live screenshot (test-artifacts/dashboard-real-playfield.png) to docs/dashboard.png.
"""

from __future__ import annotations

import itertools
import os
import re
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import pytest
from playwright.sync_api import expect

from gridfleet.grid import Cell
from gridfleet.protocol import TOPICS, FleetMap, JobsView, Routes, Topics, UnitState, decode
from gridfleet.protocol.messages import FINAL_JOB_STATES, Message
from gridfleet.robots.world import WorldSim
from gridfleet.scenario import load_scenario
from gridfleet.system.threads import ServiceThread, world_of

from support.browser import OpenDashboard
from support.paths import REPO
from support.probe import MqttProbe
from support.wait import WaitTimeout, wait_for

pytestmark = pytest.mark.browser

PLAYFIELD = REPO / "maps" / "playfield.toml"
SCENARIO = load_scenario(PLAYFIELD)
CAPACITY = {u.id: u.capacity for u in SCENARIO.units}
STARTS = {u.id: u.start for u in SCENARIO.units}
DOCS_SHOT = REPO / "docs" / "dashboard.png"

M = TypeVar("M", bound=Message)


@dataclass
class Live:
    """The running system, the page showing it, and a probe listening to what they say."""

    world: WorldSim
    dash: OpenDashboard
    probe: MqttProbe
    topics: Topics
    step_s: float

    @property
    def page(self) -> Any:
        return self.dash.page

    def latest(self, model: type[M], topic: str, kind: str) -> M | None:
        """The last message the probe saw on `topic`, decoded."""
        got = self.probe.received(topic)
        return decode(model, got[-1].payload, TOPICS[kind].max_bytes) if got else None

    def states(self, unit: str) -> list[UnitState]:
        """Every state `unit` published since the probe subscribed."""
        topic = self.topics.unit("state", unit)
        return [decode(UnitState, m.payload) for m in self.probe.received(topic)]

    def jobs(self) -> JobsView | None:
        """The coordinator's latest queue view."""
        return self.latest(JobsView, self.topics.fleet("jobs"), "jobs")

    def routes(self) -> Routes | None:
        """The coordinator's latest routes."""
        return self.latest(Routes, self.topics.fleet("routes"), "routes")

    def routes_through(self, square: tuple[int, int]) -> list[str]:
        """Units whose latest route (released or planned) runs through `square`."""
        routes = self.routes()
        if routes is None:
            return []
        return [
            u
            for u, r in routes.routes.items()
            if square in [tuple(c) for c in [*r.released, *r.planned]]
        ]

    def positions(self) -> dict[str, tuple[int, int]]:
        """Where every unit really is (the world simulation's ground truth)."""
        return {u: (c.x, c.y) for u, c in dict(self.world.positions).items()}

    def page_jobs(self) -> dict[str, dict[str, str]]:
        """Every job row on the page: its table (jobs or finished), state, unit and reason."""
        rows: dict[str, dict[str, str]] = self.page.evaluate(
            """() => Object.fromEntries([...document.querySelectorAll(
                    '#jobs tbody tr[data-job], #finished tbody tr')].map((tr) => [tr.dataset.job, {
                table: tr.closest('table').id,
                state: tr.querySelector('.state').textContent,
                unit: tr.querySelector('.unit').textContent,
                reason: tr.querySelector('.reason')?.textContent ?? '',
            }]))"""
        )
        return rows

    def record_job_states(self) -> None:
        """From now on, note every state any job row shows, in the page itself.

        The page redraws its tables a few times a second: a state shown for a second can fall
        between two of this test's looks at it (a slow machine looks less often), never between
        two of the page's own redraws.
        """
        self.page.evaluate(
            """() => {
                window.jobStatesShown = {};
                const note = () => {
                    for (const tr of document.querySelectorAll(
                            '#jobs tbody tr[data-job], #finished tbody tr[data-job]')) {
                        const state = tr.querySelector('.state')?.textContent;
                        if (state) (window.jobStatesShown[tr.dataset.job] ??= {})[state] = true;
                    }
                };
                new MutationObserver(note).observe(document.body,
                    { subtree: true, childList: true, characterData: true });
                note();
            }"""
        )

    def job_states_shown(self, job_id: str) -> set[str]:
        """Every state the page showed `job_id` in since `record_job_states`."""
        shown: list[str] = self.page.evaluate(
            "(id) => Object.keys(window.jobStatesShown?.[id] ?? {})", job_id
        )
        return set(shown)

    def record_fleets_shown(self) -> None:
        """From now on, note in the page every fleet its map draws and its list shows alike.

        Each is noted as `drawn` writes it ("unit1@3,4 unit2@..."), the moment the page shows it.
        """
        self.page.evaluate(
            """() => {
                window.fleetsShown = new Set();
                const note = () => {
                    const onMap = document.querySelector('#map').dataset.units ?? '';
                    const listed = [...document.querySelectorAll('#units tbody tr[data-unit]')]
                        .map((tr) => {
                            const square = tr.querySelector('.pos')?.textContent ?? '';
                            const [x, y] = square.replace(/[\\[\\]\\s]/g, '').split(',');
                            return `${tr.dataset.unit}@${x},${y}`;
                        });
                    if (listed.sort().join(' ') === onMap) window.fleetsShown.add(onMap);
                };
                new MutationObserver(note).observe(document.body, { subtree: true,
                    childList: true, characterData: true, attributeFilter: ['data-units'] });
                note();
            }"""
        )

    def fleets_shown(self) -> list[str]:
        """Every fleet the page showed since `record_fleets_shown`."""
        shown: list[str] = self.page.evaluate("() => [...(window.fleetsShown ?? [])]")
        return shown

    def fleets_told(self) -> set[str]:
        """Every fleet (as `drawn` writes it) the units' states made, one state after another."""
        told = [
            (seen.at, unit, decode(UnitState, seen.payload).position)
            for unit in STARTS
            for seen in self.probe.received(self.topics.unit("state", unit))
        ]
        fleet = dict(STARTS)
        fleets = set()
        for _, unit, (x, y) in sorted(told, key=lambda t: t[0]):
            fleet[unit] = Cell(x, y)
            fleets.add(drawn(fleet))
        return fleets

    def submit(
        self, job_id: str, pickup: tuple[int, int], dropoff: tuple[int, int], mass: float
    ) -> None:
        """Queue a job with the page's form and wait for the coordinator's answer."""
        self.dash.submit_job(pickup, dropoff, mass, job_id=job_id)
        expect(self.page.locator("#job-feedback")).to_contain_text(f": accepted (job {job_id})")

    def goal(self, unit: str, target: tuple[int, int]) -> None:
        """Set a goal with the page's form and wait for the coordinator to accept it."""
        self.dash.set_goal(unit, target)
        expect(self.page.locator("#goal-feedback")).to_have_text(
            f"goal [{target[0]}, {target[1]}] for {unit}: accepted"
        )


@pytest.fixture
def live(
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    open_dashboard: Callable[..., OpenDashboard],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
) -> Iterator[Callable[..., Live]]:
    """Factory: the playfield's coordinator and units running, the page open and showing them."""

    def start(step_s: float = 0.05) -> Live:
        probe = probe_factory()
        probe.subscribe(topics.all_units("state"), qos=0)
        probe.subscribe(topics.fleet("jobs"))
        probe.subscribe(topics.fleet("map"))
        probe.subscribe(topics.fleet("routes"), qos=0)
        _, fleet = run_system(PLAYFIELD, step_s=step_s)
        dash = open_dashboard()
        # The page knows the real fleet: the coordinator's map and every unit where it stands.
        expect(dash.page.locator("#map-name")).to_have_text("playfield 10 x 10")
        expect(dash.page.locator("#coord")).to_contain_text("coordinator: online")
        live = Live(world_of(fleet), dash, probe, topics, step_s)
        expect(dash.page.locator("#map")).to_have_attribute("data-units", drawn(live.positions()))
        return live

    yield start


def drawn(positions: dict[str, tuple[int, int]]) -> str:
    """The map canvas's `data-units` for these positions."""
    return " ".join(sorted(f"{u}@{x},{y}" for u, (x, y) in positions.items()))


def unit_rows(live: Live) -> dict[str, dict[str, str]]:
    """The units panel: per unit, its link, square, status, job and load as shown."""
    rows: dict[str, dict[str, str]] = live.page.evaluate(
        """() => Object.fromEntries([...document.querySelectorAll('#units tbody tr[data-unit]')].map(
            (tr) => [tr.dataset.unit, Object.fromEntries([...tr.children].map(
                (td) => [td.className, td.textContent]))]))"""
    )
    return rows


def playfield_jobs() -> list[tuple[str, tuple[int, int], tuple[int, int], float]]:
    """The playfield scenario's jobs as (id, pickup, dropoff, mass)."""
    return [
        (f"job-{i + 1}", (j.pickup.x, j.pickup.y), (j.dropoff.x, j.dropoff.y), j.mass)
        for i, j in enumerate(SCENARIO.jobs)
    ]


def obstacles_drawn(live: Live) -> set[tuple[int, int]]:
    """The squares the map canvas draws as discovered obstacles."""
    text = live.page.locator("#map").get_attribute("data-obstacles") or ""
    found = set()
    for item in text.split():
        x, y = item.rstrip("*").split(",")
        found.add((int(x), int(y)))
    return found


# ---- item 3 ------------------------------------------------------------------------------------


def test_03_obstacle_sensed_by_a_unit_shows_on_the_dashboard(live: Callable[..., Live]) -> None:
    system = live()
    hidden = Cell(7, 2)
    # Hidden: in the world's truth, not on the map the coordinator starts from, not on the page.
    assert hidden in system.world.hidden and SCENARIO.grid.is_free(hidden)
    fleet_map = system.latest(FleetMap, system.topics.fleet("map"), "map")
    assert fleet_map is not None and [7, 2] not in [list(o) for o in fleet_map.obstacles]
    assert obstacles_drawn(system) == set()

    # unit2 goes to (7, 1), next to the hidden obstacle: its south sensor sees it.
    system.goal("unit2", (7, 1))
    wait_for(lambda: system.world.positions["unit2"] == (7, 1), timeout=15, what="unit2 at (7, 1)")
    # On the page's map, highlighted as just discovered ("*") for a few seconds: checked first,
    # before the mark fades on a slow machine.
    expect(system.page.locator("#map")).to_have_attribute("data-obstacles", "7,2*")
    # unit2 reports what its sensor saw (the state published after that step's move).
    system.probe.wait(
        system.topics.unit("state", "unit2"),
        lambda m: [7, 2] in [list(o) for o in decode(UnitState, m.payload).obstacles],
    )
    system.probe.wait(
        system.topics.fleet("map"),
        lambda m: (
            [7, 2]
            in [list(o) for o in decode(FleetMap, m.payload, TOPICS["map"].max_bytes).obstacles]
        ),
    )
    # Nothing that was not sensed is on the page.
    assert (4, 5) not in obstacles_drawn(system)  # the other hidden obstacle: nobody saw it yet
    # The coordinator plans around it: straight down would be shortest, the route goes round.
    system.goal("unit2", (7, 4))
    wait_for(lambda: system.world.positions["unit2"] == (7, 4), timeout=15, what="unit2 at (7, 4)")
    routes = [
        decode(Routes, m.payload, TOPICS["routes"].max_bytes)
        for m in system.probe.received(system.topics.fleet("routes"))
    ]
    assert any(r.routes.get("unit2") and r.routes["unit2"].target == (7, 4) for r in routes)
    for r in routes:
        view = r.routes.get("unit2")
        if view is not None and view.target == (7, 4):
            assert (7, 2) not in [tuple(c) for c in [*view.released, *view.planned]], view
    # A reload recovers it from the coordinator's retained map alone.
    system.page.reload()
    system.dash.wait_connected()
    wait_for(lambda: obstacles_drawn(system) == {(7, 2)}, what="(7, 2) drawn after a reload")
    assert system.world.collisions == 0
    assert system.dash.errors == []


# ---- item 8 ------------------------------------------------------------------------------------


def test_08_jobs_entered_on_the_page_are_done_deleted_or_refused(
    live: Callable[..., Live],
) -> None:
    system = live(step_s=0.1)
    system.record_job_states()
    jobs_topic = system.topics.fleet("jobs")
    # Two 15 kg jobs: only unit4 (20 kg) carries them, so the second waits in the queue.
    system.submit("heavy-1", (1, 1), (8, 1), 15)
    system.submit("heavy-2", (1, 8), (8, 8), 15)
    system.submit("light-1", (5, 0), (5, 9), 4)  # unit2, unit3 or unit4; never unit1 (2 kg)

    # heavy-2 is listed as queued (pending) while unit4 works on heavy-1; the operator deletes it.
    wait_for(
        lambda: (
            system.page_jobs().get("heavy-2", {}).get("state") == "queued"
            and system.page_jobs().get("heavy-1", {}).get("unit") == "unit4"
        ),
        what="heavy-1 with unit4 and heavy-2 queued on the page",
    )
    system.dash.cancel_job("heavy-2")
    expect(system.page.locator("#cancel-feedback")).to_have_text("delete job heavy-2: accepted")
    cancelled = system.page.locator("#finished tr[data-job='heavy-2']")
    expect(cancelled.locator(".state")).to_have_text("cancelled")
    expect(cancelled.locator(".reason")).to_contain_text("cancelled by dash-test")
    expect(system.page.locator("#jobs tr[data-job='heavy-2']")).to_have_count(0)

    # A job no unit can carry: the coordinator's reason, in words, next to the form.
    system.dash.submit_job((0, 5), (9, 5), 50)
    reason = "mass 50.0 kg exceeds every unit's capacity (largest 20.0 kg)"
    feedback = system.page.locator("#job-feedback")
    expect(feedback).to_have_attribute("data-kind", "refused")
    expect(feedback).to_have_text(re.compile(rf"refused — {re.escape(reason)}$"))

    # The others get done, each by a unit whose capacity covers it, seen on the page as it goes.
    def finished() -> bool:
        rows = system.page_jobs()
        return all(rows.get(j, {}).get("state") == "done" for j in ("heavy-1", "light-1"))

    wait_for(finished, timeout=30, what="heavy-1 and light-1 done on the page")
    rows = system.page_jobs()
    view = system.jobs()
    assert view is not None
    truth = {j.id: j for j in view.listed()}
    for job_id, mass in (("heavy-1", 15), ("light-1", 4)):
        unit = rows[job_id]["unit"]
        assert rows[job_id]["table"] == "finished" and unit == truth[job_id].unit
        assert CAPACITY[unit] >= mass, f"{job_id} ({mass} kg) done by {unit}"
        shown = system.job_states_shown(job_id)
        assert shown & {"assigned", "to_pickup", "loaded", "to_dropoff"}, shown
        # The unit really carried it: loaded at the pickup, then at the dropoff, then empty.
        states = system.states(unit)
        carrying = [i for i, s in enumerate(states) if s.job_id == job_id]
        assert carrying and states[carrying[0]].position == tuple(truth[job_id].pickup)
        after = states[carrying[-1] + 1 :]
        assert after and after[0].position == tuple(truth[job_id].dropoff)
        assert after[0].job_id is None and after[0].load_kg == 0
    assert rows["heavy-1"]["unit"] == "unit4"
    deleted = truth["heavy-2"]
    assert deleted.state == "cancelled"
    # Still queued when deleted; on a busy machine unit4 may have finished heavy-1 and taken it
    # by the time the deletion arrived: then the unit was released, and the reason says so.
    if deleted.unit is not None:
        assert deleted.unit == "unit4" and "unit unit4 released" in (deleted.reason or "")
    assert [j.state for j in view.listed() if j.mass_kg == 50] == ["rejected"]
    expect(system.page.locator("#queue-count")).to_have_text("(0)")
    expect(system.page.locator("#finished-counts")).to_have_text(
        "done 2 · cancelled 1 · rejected 1"
    )
    assert len(system.probe.received(jobs_topic)) >= 5
    assert system.world.collisions == 0
    assert system.dash.errors == []


def test_08_set_goal_by_clicking_and_the_emergency_stop(live: Callable[..., Live]) -> None:
    system = live(step_s=0.1)
    page, world = system.page, system.world
    # Click a unit on the map to choose it, then the square it should go to.
    page.locator("input[name=clickmode][value=goal]").check()
    system.dash.click_square(0, 9)
    expect(page.locator("#units tr.selected")).to_have_attribute("data-unit", "unit3")
    system.dash.click_square(9, 1)
    expect(page.locator("#goal-feedback")).to_have_text("goal [9, 1] for unit3: accepted")
    goals = {"unit3": (9, 1), "unit1": (9, 8), "unit2": (0, 8), "unit4": (0, 1)}
    for unit in ("unit1", "unit2", "unit4"):
        system.goal(unit, goals[unit])
    wait_for(
        lambda: all(world.moves[u] >= 2 for u in goals),
        timeout=10,
        what="every unit under way",
    )
    under_way = [u for u in goals if system.positions()[u] != goals[u]]
    assert len(under_way) >= 3, f"too late to test the stop: only {under_way} under way"

    # One click on STOP: every unit stops within one of its steps of hearing it.
    estop_topic = system.topics.fleet("estop")
    system.probe.subscribe(estop_topic)
    system.dash.press_stop()
    page_id = page.evaluate("document.body.dataset.clientId")  # the latch names the page
    system.probe.wait(estop_topic, lambda m: m.payload.startswith(f"engaged|{page_id}|".encode()))
    expect(page.locator("body")).to_have_attribute("data-estop", "engaged")
    expect(page.locator("#estop-banner")).to_contain_text(f"EMERGENCY STOP — engaged by {page_id}")
    expect(page.locator("#stop")).to_have_text("STOPPED")
    wait_for(
        lambda: all(system.states(u)[-1].status == "stopped" for u in goals),
        what="every unit reporting stopped",
    )
    stopped_at = system.positions()
    stopped_moves = dict(world.moves)
    for unit in goals:
        # Each unit's first state with the stop says stopped where it still stands: it drove no
        # square after it heard the stop (the units hear it at their own pace, not the probe's).
        first = next(s for s in system.states(unit) if s.estop)
        assert first.status == "stopped" and first.released == [], (unit, first)
        assert tuple(first.position) == tuple(stopped_at[unit]), (unit, first, stopped_at)
    # Several steps later (counted by the units' own state reports) nobody has moved.
    since = {u: system.states(u)[-1].step for u in goals}
    wait_for(
        lambda: all(system.states(u)[-1].step >= since[u] + 5 for u in goals),
        what="five more steps of every unit",
    )
    assert system.positions() == stopped_at and dict(world.moves) == stopped_moves
    expect(page.locator("#map")).to_have_attribute("data-units", drawn(stopped_at))
    wait_for(
        lambda: (
            {u: row["status"] for u, row in unit_rows(system).items()}
            == dict.fromkeys(goals, "stopped: emergency stop engaged")
        ),
        what="every unit listed as stopped on the page",
    )
    system.dash.screenshot("acceptance-dashboard-stopped")

    # The deliberate release (press and hold) resumes motion; every unit reaches its goal.
    system.dash.hold_release()
    expect(page.locator("body")).to_have_attribute("data-estop", "released")
    expect(page.locator("#estop-banner")).to_be_hidden()
    wait_for(
        lambda: system.positions() == goals, timeout=30, what="every unit at its goal after release"
    )
    assert sum(world.moves.values()) > sum(stopped_moves.values())
    expect(page.locator("#map")).to_have_attribute("data-units", drawn(goals))
    assert world.collisions == 0
    assert system.dash.errors == []


# ---- item 9 ------------------------------------------------------------------------------------


@pytest.mark.timeout(150)  # its waits add up to 110 s: a slow run fails on the one that is late
def test_09_dashboard_shows_positions_done_and_pending_tasks(live: Callable[..., Live]) -> None:
    system = live(step_s=0.1)
    # The playfield's jobs, and one more 15 kg job that must wait for unit4 (the only one able).
    jobs = playfield_jobs()
    jobs.append(("job-5", (2, 9), (9, 6), 15.0))
    system.record_job_states()
    system.record_fleets_shown()
    for job_id, pickup, dropoff, mass in jobs:
        system.submit(job_id, pickup, dropoff, mass)

    # As the units move, the page draws and lists each one where the world has it: five fleets
    # the page showed (map and list alike) are fleets the units' states told, in the order they
    # came. The page's are noted in the page itself as it shows them: a look from here takes
    # longer than a step on a loaded machine, and the page and the world caught in the same
    # instant by two looks were too rare (a CI flake).
    def tracks_the_world() -> bool:
        shown = set(system.fleets_shown()) - {drawn(STARTS)}
        return len(shown & system.fleets_told()) >= 5

    wait_for(tracks_the_world, timeout=40, interval=0.2, what="five moving fleets matched")

    # Mid-run: pending and done jobs listed, with counts, as the coordinator has them.
    def lists_match_the_coordinator() -> bool:
        view = system.jobs()
        if view is None:
            return False
        done = {j.id for j in view.listed() if j.state == "done"}
        pending = {j.id for j in view.listed() if j.state not in FINAL_JOB_STATES}
        if not done or not pending:
            return False
        rows = system.page_jobs()
        shown_pending = {j for j, r in rows.items() if r["table"] == "jobs"}
        shown_done = {
            j for j, r in rows.items() if r["table"] == "finished" and r["state"] == "done"
        }
        count = system.page.locator("#queue-count").text_content()
        counts = system.page.locator("#finished-counts").text_content()
        as_coordinator = {j.id: (j.state, j.unit or "—") for j in view.listed() if j.id in pending}
        return (
            shown_pending == pending
            and {j: (rows[j]["state"], rows[j]["unit"]) for j in pending} == as_coordinator
            and shown_done == done
            and count == f"({len(pending)})"
            and counts == f"done {len(done)}"
        )

    wait_for(lists_match_the_coordinator, timeout=30, what="pending and done jobs listed")

    # At the end: every job done by a unit able to carry it, the queue empty, the counts right.
    def where() -> str:
        view = system.jobs()
        states = {j.id: (j.state, j.unit, j.wait_reason) for j in view.listed()} if view else None
        return f"page {system.page_jobs()}; coordinator {states}; units {unit_rows(system)}"

    wait_for(
        lambda: (
            all(r["state"] == "done" for r in system.page_jobs().values())
            and len(system.page_jobs()) == len(jobs)
        ),
        timeout=40,
        what="every job done on the page",
        context=where,
    )
    expect(system.page.locator("#queue-count")).to_have_text("(0)")
    expect(system.page.locator("#finished-counts")).to_have_text(f"done {len(jobs)}")
    rows = system.page_jobs()
    for job_id, _, _, mass in jobs:
        assert CAPACITY[rows[job_id]["unit"]] >= mass, (job_id, rows[job_id])
    # It was listed as pending before unit4 took it.
    assert "queued" in system.job_states_shown("job-5"), system.job_states_shown("job-5")
    expect(system.page.locator("#map")).to_have_attribute("data-units", drawn(system.positions()))
    assert system.world.collisions == 0
    assert system.dash.errors == []


# ---- the README's picture ----------------------------------------------------------------------


@pytest.mark.timeout(180)  # waits for a moment of the run, which a loaded machine makes rarer
def test_09_screenshot_of_the_live_playfield(live: Callable[..., Live]) -> None:
    """docs/dashboard.png: the page on the real playfield, mid-run (see the module docstring)."""
    system = live(step_s=0.25)
    # A short job first, so the picture has a finished one.
    system.submit("job-0", (1, 0), (3, 0), 1.0)
    wait_for(
        lambda: system.page_jobs().get("job-0", {}).get("state") == "done",
        timeout=20,
        what="job-0 done",
    )
    numbers = itertools.count(1)

    def give_work() -> None:
        # The 15 kg job first, so unit4 (the only one able) takes it and unit3 the 8 kg one: the
        # whole fleet at work. The last one, 15 kg too, then waits for unit4.
        jobs = sorted(playfield_jobs(), key=lambda j: -j[3])
        for _, pickup, dropoff, mass in [*jobs, ("", (2, 9), (9, 6), 15.0)]:
            system.submit(f"job-{next(numbers)}", pickup, dropoff, mass)

    give_work()
    system.dash.submit_job((0, 5), (9, 5), 50, job_id="too-heavy")
    expect(system.page.locator("#job-feedback")).to_have_attribute("data-kind", "refused")

    # Mid-run: three units under way (arrows lit), an item on board, a job waiting, and no route
    # through a known obstacle (not in the instant between a unit's discovery and the re-plan).
    last: dict[str, object] = {}

    def under_way() -> list[str] | None:
        """The units with a lit arrow when the moment holds, else []; None once no job waits."""
        arrows = system.page.locator("#map").get_attribute("data-headings") or ""
        heading = [u for u, _, d in (a.partition(":") for a in arrows.split()) if d != "-"]
        states = {r["state"] for r in system.page_jobs().values()}
        known = obstacles_drawn(system)
        through = [sq for sq in known if system.routes_through(sq)]
        last.update(
            heading=heading,
            job_states=sorted(states),
            obstacles=sorted(known),
            routes_through_obstacles=through,
        )
        if "queued" not in states:
            return None
        if through or len(heading) < 3 or not states & {"loaded", "to_dropoff"}:
            return []
        return heading

    def picture() -> Path | None:
        heading = under_way()
        if heading is None:
            # The moment passed between two looks (a loaded machine looks less often): once more.
            give_work()
            return None
        # Two of them moving this very step: a step's status, which changes every step, so it is
        # asked before the picture only.
        moving = [u for u, r in unit_rows(system).items() if r["status"].startswith("moving")]
        last.update(moving=moving)
        if len(set(heading) & set(moving)) < 2:
            return None
        # The side panel from its top (filling the job form scrolled it down to the form).
        system.page.locator("#side").evaluate("(side) => { side.scrollTop = 0; }")
        shot = system.dash.screenshot("dashboard-real-playfield")
        # Kept only when the moment held from before the picture until after it.
        return shot if under_way() else None

    try:
        shot = wait_for(picture, timeout=120, interval=0.05, what="the moment")
    except WaitTimeout as timeout:
        pytest.fail(
            f"{timeout}; units under way, an item on board, a job waiting? last look: {last}"
        )
    expect(system.page.locator("#coord")).to_have_text(
        # After its first few seconds the coordinator also says the step it achieves.
        re.compile(
            r"^coordinator: online, step [1-9][0-9]*( · [0-9.]+ m?s a step \(set 250 ms\))?$"
        )
    )
    assert shot.stat().st_size > 10_000
    if os.environ.get("GRIDFLEET_REFRESH_DOCS"):
        shutil.copyfile(shot, DOCS_SHOT)
    assert system.world.collisions == 0
    assert system.dash.errors == []
