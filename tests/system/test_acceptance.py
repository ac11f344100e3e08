"""The course's acceptance list (the course manual's Appendix A), one test per item, against the running system.

Each run is `gridfleet simulate`'s own code: the real coordinator and simulated units over the
real broker, with the scenario's jobs and goals submitted over the protocol. Items 5 and 6 (the
unit's LEDs, the device) and 8 and 9 (the dashboard in Chromium) have files of their own:
tests/system/test_acceptance_device.py and tests/system/test_acceptance_dashboard.py.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import pytest

from gridfleet.console.monitor import FleetMonitor
from gridfleet.grid import Cell, GridMap
from gridfleet.paths import UNREACHABLE, DistanceFieldCache
from gridfleet.protocol import Topics
from gridfleet.scenario import Scenario, load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.simulate import SimulationResult, simulate

from support.paths import MAPS
from support.probe import MqttProbe
from support.wait import wait_for

pytestmark = [
    pytest.mark.slow,
    pytest.mark.every_broker,
]  # the course's acceptance, broker items included (the latest messages kept)

STEP_S = 0.05
MAX_STEPS = 600  # a few times what any of these scenarios needs; ends well inside the timeout

Run = Callable[..., "tuple[Scenario, SimulationResult]"]


@pytest.fixture
def run_scenario(broker: BrokerThread, root: str) -> Run:
    """Run a shipped scenario to the end on the session broker; fail unless it finished."""

    async def run(
        name: str, *, sensors_see_units: bool = True
    ) -> tuple[Scenario, SimulationResult]:
        scenario = load_scenario(MAPS / f"{name}.toml")
        outcome = await simulate(
            scenario,
            STEP_S,
            MAX_STEPS,
            root,
            broker.url,
            record=True,
            sensors_see_units=sensors_see_units,
        )
        if not outcome.finished:
            tail = "\n".join(
                f"{s.step} {s.header.sender} {list(s.position)} {s.status} {s.wait_reason} "
                f"released={s.released} update={s.order_update_id}"
                for s in monitor_of(outcome).history[-30:]
            )
            pytest.fail(f"{name} did not finish in {outcome.steps} steps: {outcome.jobs}\n{tail}")
        return scenario, outcome

    return run  # type: ignore[return-value]


def monitor_of(outcome: SimulationResult) -> FleetMonitor:
    assert outcome.monitor is not None
    return outcome.monitor


def published_track(outcome: SimulationResult, unit: str) -> list[Cell]:
    """The unit's positions as it published them, without repeats."""
    track: list[Cell] = []
    for state in monitor_of(outcome).history:
        if state.header.sender == unit and (not track or track[-1] != state.position):
            track.append(Cell(*state.position))
    return track


def final_position(outcome: SimulationResult, unit: str) -> Cell:
    return Cell(*next(u["position"] for u in outcome.units if u["id"] == unit))


async def test_01_a_unit_moves_in_the_simulated_space(run_scenario: Run) -> None:
    scenario, outcome = await run_scenario("corridor")
    for spec in scenario.units:
        track = published_track(outcome, spec.id)
        assert track[0] == spec.start
        assert track[-1] == final_position(outcome, spec.id)  # the published pose is the truth
        assert all(a.manhattan(b) == 1 for a, b in itertools.pairwise(track))
        moves = next(u["moves"] for u in outcome.units if u["id"] == spec.id)
        assert moves == len(track) - 1 > 0  # every move in the world was published


@pytest.mark.parametrize("name", ["corridor", "crossing", "maze", "playfield"])
async def test_02_units_avoid_other_units_and_obstacles(run_scenario: Run, name: str) -> None:
    # Sensors blind to other units: the units follow their orders alone, so any order that led
    # a unit into an occupied square would show up as a prevented move. Layer two (the unit's
    # own sensor) is tested with every other run, where it must never be needed either.
    _, outcome = await run_scenario(name, sensors_see_units=False)
    assert outcome.collisions == 0
    assert outcome.prevented == 0
    assert sum(u["moves"] for u in outcome.units) > 0


def test_02_the_maze_hides_an_obstacle_on_a_shortest_route() -> None:
    # So that avoiding it is forced, not luck: some job or goal's shortest route on the map the
    # fleet knows at the start runs through a hidden obstacle.
    scenario = load_scenario(MAPS / "maze.toml")
    known = DistanceFieldCache(scenario.grid)
    truth = DistanceFieldCache(scenario.grid.with_blocked(scenario.hidden_obstacles))
    legs = [(j.pickup, j.dropoff) for j in scenario.jobs]
    legs += [(u.start, g.target) for g in scenario.goals for u in scenario.units if u.id == g.unit]
    assert any(truth.distance(a, b) > known.distance(a, b) for a, b in legs)


async def test_03_units_exchange_positions_and_obstacles_with_the_server(
    run_scenario: Run,
) -> None:
    scenario, outcome = await run_scenario("maze")
    monitor = monitor_of(outcome)
    assert monitor.map is not None
    on_map = {Cell(*c) for c in monitor.map.obstacles}
    reported = {Cell(*c) for s in monitor.history for c in s.obstacles}
    assert reported, "no unit sensed a hidden obstacle"
    assert reported <= set(scenario.hidden_obstacles)  # never another unit, never a wall
    assert reported <= on_map  # what one unit sensed, the server shares with all
    for spec in scenario.units:
        assert Cell(*monitor.states[spec.id].position) == final_position(outcome, spec.id)


async def test_04_units_reach_their_goals(run_scenario: Run) -> None:
    scenario, outcome = await run_scenario("crossing")
    assert [g["reached"] for g in outcome.goals] == [True] * len(scenario.goals) > []
    for goal in scenario.goals:
        assert final_position(outcome, goal.unit) == goal.target


def _known_grid(scenario: Scenario, obstacles: list[Cell]) -> GridMap:
    return scenario.grid.with_blocked(obstacles)


async def test_07_routes_come_from_an_algorithm(run_scenario: Run) -> None:
    # Every route the coordinator publishes is continuous, avoids walls and known obstacles,
    # ends on the unit's target, and its planned part is a shortest path on the known map.
    scenario, outcome = await run_scenario("maze")
    monitor = monitor_of(outcome)
    obstacles = [Cell(*c) for c in monitor.map.obstacles] if monitor.map else []
    grid = _known_grid(scenario, obstacles)
    fields = DistanceFieldCache(grid)
    checked = 0
    for view in monitor.routes:
        for unit, route in view.routes.items():
            if route.target is None or not route.planned:
                continue
            path = [Cell(*c) for c in route.released + route.planned]
            assert all(a.manhattan(b) == 1 for a, b in itertools.pairwise(path)), unit
            assert path[-1] == Cell(*route.target)
            # Obstacles found later may block an early route: check against what was known
            # then, i.e. only squares the scenario's map itself has free must be free.
            assert all(scenario.grid.is_free(c) for c in path), (unit, path)
            start = Cell(*route.released[-1]) if route.released else None
            if start is not None and all(grid.is_free(c) for c in path):
                assert len(route.planned) == fields.distance(start, path[-1]) != UNREACHABLE
                checked += 1
    assert checked > 10


async def test_10_tasks_are_divided_according_to_each_units_constraints(
    run_scenario: Run,
) -> None:
    scenario, outcome = await run_scenario("heavy")
    capacity = {u.id: u.capacity for u in scenario.units}
    strongest = max(capacity, key=capacity.__getitem__)
    heaviest_feasible = max(
        (j for j in outcome.jobs if j["mass"] <= capacity[strongest]), key=lambda j: j["mass"]
    )
    assert heaviest_feasible["state"] == "done"
    assert sum(c >= heaviest_feasible["mass"] for c in capacity.values()) == 1
    assert heaviest_feasible["unit"] == strongest  # the only unit that can carry it
    for job in outcome.jobs:
        if job["state"] == "done":
            assert capacity[job["unit"]] >= job["mass"], job
        else:
            assert job["state"] == "rejected" and job["mass"] > capacity[strongest], job
            assert "capacity" in job["reason"], job


async def test_server_keeps_the_latest_messages_for_a_late_client(
    run_scenario: Run, broker: BrokerThread, topics: Topics
) -> None:
    scenario, outcome = await run_scenario("playfield")
    # Everybody has gone. A client that connects now still gets the whole state at once.
    with MqttProbe(broker.url) as late:
        late.subscribe(f"{topics.prefix}/#")
        expected = [topics.fleet(kind) for kind in ("map", "jobs", "coordinator")]
        for spec in scenario.units:
            expected += [topics.unit(k, spec.id) for k in ("state", "factsheet", "connection")]
        wait_for(lambda: all(late.received(t) for t in expected), what="every retained topic")
        assert all(m.retain for t in expected for m in late.received(t))
        for spec in scenario.units:
            assert (
                late.received(topics.unit("connection", spec.id))[-1].payload.find(b'"offline"')
                >= 0
            )
        done = sum(j["state"] == "done" for j in outcome.jobs)
        jobs_view = late.received(topics.fleet("jobs"))[-1].payload
        assert jobs_view.count(b'"done"') >= done == len(scenario.jobs)
