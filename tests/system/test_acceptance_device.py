"""Acceptance: a unit shows its intended direction, the device follows it, its stop halts the fleet.

Everything runs for real over the session broker: the coordinator and the simulated units of a
shipped scenario (the `run_system` fixture), the virtual device (`device.shell`) and an
operator (`OperatorPeer`, tests/support/operator_peer.py) that sends goals, reads every unit's
state and watches the topics the dashboard reads.
"""

from __future__ import annotations

import asyncio
import itertools
import time
from collections.abc import Callable
from typing import Any, TypeVar

import pytest

from gridfleet.device.core import DeviceCore
from gridfleet.device.shell import DeviceShell
from gridfleet.grid import Cell, Direction
from gridfleet.protocol import Leds, Topics, UnitState, decode_direction, decode_estop
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, world_of

from support.operator_peer import OperatorPeer
from support.paths import MAPS
from support.probe import MqttProbe
from support.wait import async_wait_for, wait_for

pytestmark = pytest.mark.slow  # seconds a test: in make test, not in test-fast

STEP_S = 0.05
ALL = Leds(N=True, E=True, S=True, W=True)
T = TypeVar("T")
RunSystem = Callable[..., tuple[ServiceThread, ServiceThread]]
OPERATOR = "acceptance-op"
RELEASE_REASON = "area checked"  # the operator's deliberate release


def lit(leds: Leds) -> set[str]:
    """The sides whose LED is lit."""
    return {side for side, on in leds.model_dump().items() if on}


def send_goal(op: OperatorPeer, unit: str, target: Cell) -> None:
    """Send `unit` to `target`; retried while the coordinator does not know the unit yet."""

    def accepted() -> bool:
        reply = op.set_goal(unit, target)
        assert reply.accepted or "unknown unit" in (reply.reason or ""), reply.reason
        return reply.accepted

    wait_for(accepted, 10, interval=STEP_S, what=f"goal {target} for {unit} accepted")


def step_of(op: OperatorPeer, unit: str) -> int:
    """The step of `unit`'s newest state (it must have published one)."""
    state = op.last_state(unit)
    assert state is not None, f"no state of {unit} yet"
    return state.step


def stepped_past(op: OperatorPeer, marks: dict[str, int], n: int) -> bool:
    """Whether every unit has published a state at least `n` steps after its mark."""
    for unit, mark in marks.items():
        state = op.last_state(unit)
        if state is None or state.step < mark + n:
            return False
    return True


def coordinator_estop(op: OperatorPeer) -> bool | None:
    """The `estop` flag of the coordinator's newest status (shown by the dashboard too)."""
    status = op.coordinator_status()
    return None if status is None else status.estop


def dedup(seq: list[T]) -> list[T]:
    """`seq` without repeats of the previous entry: the changes a person would see."""
    return [x for i, x in enumerate(seq) if i == 0 or x != seq[i - 1]]


def assert_follows(shown: list[T], published: list[T]) -> None:
    """`shown` is every change of `published`, in order; QoS 0 may lose a few (protocol §3).

    On a quiet machine the two are equal; under load the broker may drop a QoS 0 message, so
    up to 10 % may be missing, but nothing may be extra, reordered or made up.
    """
    if shown == published:
        return
    it = iter(published)
    assert all(x in it for x in shown), f"shown {shown} is not in the order of {published}"
    assert len(shown) >= 0.9 * len(published) - 1, f"shown {shown} misses much of {published}"


def in_order(sub: list[T], seq: list[T]) -> int:
    """How many of `sub` appear in `seq` in the same order (the longest common subsequence)."""
    row = [0] * (len(seq) + 1)
    for x in sub:
        diagonal = 0
        for j, y in enumerate(seq, 1):
            diagonal, row[j] = row[j], diagonal + 1 if x == y else max(row[j], row[j - 1])
    return row[-1]


def check_intentions(unit: str, shown: list[tuple[UnitState | None, Leds]]) -> int:
    """Check what one unit showed against protocol §4.3 and §4.6; returns the moves it checked.

    Every state lights exactly the LED of its `direction` (none for `-`), all four while
    stopped; every move between two consecutive states (no QoS 0 gap in `seq`) is one square in
    the direction the display showed last before it (a state's, or the direction topic's); a unit
    that showed a direction and then stepped either made exactly that move, or was stopped or
    holding, or its own sensor saw a unit still in the square it was released.
    """
    states = [s for s, _ in shown if s is not None]
    before_each: dict[int, Leds] = {}  # a state's seq -> the LEDs shown just before it
    last = Leds()
    for s, leds in shown:
        if s is not None:
            before_each[s.header.seq] = last
        last = leds
    moves = waits = 0
    for s in states:
        if s.estop or s.status == "stopped":
            assert s.estop and s.status == "stopped", f"{unit} step {s.step}: {s.status} {s.estop}"
            assert lit(s.leds) == set("NESW"), f"{unit} step {s.step}: stop pattern {s.leds}"
        else:
            want = set() if s.direction == "-" else {s.direction}
            assert lit(s.leds) == want, f"{unit} step {s.step}: {s.leds} for {s.direction}"
    for before, after in itertools.pairwise(states):
        if after.header.seq != before.header.seq + 1:
            continue  # a state lost on QoS 0: nothing to compare across the gap
        here, there = Cell(*before.position), Cell(*after.position)
        if after.step == before.step:
            assert there == here, f"{unit} moved without a step at {before.step}"
            continue
        lit_before = lit(before_each[after.header.seq])
        if len(lit_before) != 1 or before.estop:
            assert there == here, f"{unit} moved {here}->{there} without showing a direction"
            continue
        (showed,) = lit_before
        if after.status in ("stopped", "holding"):
            assert there == here, f"{unit} moved while {after.status}"
            continue
        if there == here and after.wait_reason and "blocked by another unit" in after.wait_reason:
            # Released behind a unit that had not left yet: its own sensor saw it, so it waited
            # (protocol §4.4 rule 4) and shows the direction again, or another, next.
            waits += 1
            continue
        expected = here.step(Direction(showed))
        assert there == expected, (
            f"{unit} showed {showed} at {here} (step {before.step}) "
            f"but is at {there} ({after.status}: {after.wait_reason})"
        )
        moves += 1
    assert waits <= moves, f"{unit} waited behind units {waits} times for {moves} moves"
    return moves


# -- test_05: the unit's own LEDs --------------------------------------------------------------


@pytest.mark.timeout(150)  # its waits add up to more than 60 s: a slow run fails on the late one
def test_05_the_unit_shows_its_intended_direction_every_step(
    run_system: RunSystem, probe_factory: Callable[..., MqttProbe], topics: Topics
) -> None:
    from gridfleet.scenario import load_scenario

    scenario = load_scenario(MAPS / "crossing.toml")
    units = [u.id for u in scenario.units]
    goals = {g.unit: Cell(*g.target) for g in scenario.goals}
    assert sorted(goals) == sorted(units)  # every unit crosses to the opposite arm: they meet
    op = OperatorPeer(probe_factory(), topics, OPERATOR)
    _, fleet = run_system(scenario, step_s=STEP_S)
    world = world_of(fleet)
    for unit, target in goals.items():
        send_goal(op, unit, target)
    wait_for(lambda: all(world.moves[u] >= 2 for u in units), 15, what="every unit under way")

    # An emergency stop in the middle of the crossing, so stopped states are checked too.
    op.engage("test", by="tester")
    wait_for(lambda: all((s := op.last_state(u)) and s.estop for u in units), 5, what="all stopped")
    marks = {u: step_of(op, u) for u in units}
    wait_for(lambda: stepped_past(op, marks, 3), 5, what="three steps while stopped")
    op.release(RELEASE_REASON)

    wait_for(
        lambda: all(world.positions[u] == g for u, g in goals.items()),
        30,
        what="every unit at its goal",
    )
    wait_for(
        lambda: all(
            (s := op.last_state(u)) and s.status == "idle" and s.direction == "-" for u in units
        ),
        5,
        what="every unit idle",
    )
    assert world.collisions == 0
    checked = {u: check_intentions(u, op.display(u)) for u in units}
    for unit in units:
        # The device topic carries every change of the state's direction, in order (and an
        # order's first move between two steps): QoS 0 may lose a few (protocol §3).
        told = dedup([decode_direction(s.direction) for s in op.states(unit)])
        assert in_order(told, dedup(op.directions(unit))) >= 0.9 * len(told) - 1, unit
    stopped = {u: sum(s.status == "stopped" for s in op.states(u)) for u in units}
    # Nothing vacuous: (nearly) every move was compared, and every unit was seen stopped.
    assert sum(checked.values()) >= 0.9 * sum(world.moves.values()), (checked, world.moves)
    for unit in units:
        # Stopped for three steps: the state that showed the stop, and the heartbeat a unit
        # standing still sends at least every third step (protocol.md §4.3).
        assert checked[unit] >= 3 and stopped[unit] >= 2, (unit, checked, stopped)


# -- test_06: the (virtual) device -------------------------------------------------------------


@pytest.mark.timeout(150)  # its waits add up to more than 60 s: a slow run fails on the late one
async def test_06_direction_on_the_device_and_its_emergency_stop_works(
    run_system: RunSystem,
    probe_factory: Callable[..., MqttProbe],
    broker: BrokerThread,
    topics: Topics,
    root: str,
) -> None:
    from gridfleet.scenario import load_scenario

    scenario = load_scenario(MAPS / "playfield.toml")
    units = [u.id for u in scenario.units]
    starts = {u.id: u.start for u in scenario.units}
    op = await asyncio.to_thread(lambda: OperatorPeer(probe_factory(), topics, OPERATOR))
    _, fleet = await asyncio.to_thread(run_system, scenario, STEP_S)
    world = world_of(fleet)

    shown: list[Leds] = []  # every LED state the device showed, in order

    def record(logic: DeviceCore) -> None:
        if logic.online:
            shown.append(logic.leds)

    device = DeviceShell(broker.url, "unit1", root, device_id="dev-accept", on_change=record)
    stop = asyncio.Event()
    task = asyncio.create_task(device.run(stop))
    try:
        await async_wait_for(lambda: device.online or task.done(), what="device online")
        assert not task.done(), task.exception()
        await async_wait_for(
            lambda: all((s := op.last_state(u)) and s.status == "idle" for u in units), what="idle"
        )
        assert device.leds == Leds()  # unit1 stands still: nothing lit

        # 1. The device follows unit1 while all four units cross the field.
        goals = {"unit1": Cell(9, 3), "unit2": Cell(0, 3), "unit3": Cell(9, 6), "unit4": Cell(0, 6)}
        before = op.states("unit1")
        assert before and before[-1].leds == Leds()
        since = time.monotonic()  # what the unit shows from here on
        for unit, target in goals.items():
            await asyncio.to_thread(send_goal, op, unit, target)
        await async_wait_for(
            lambda: all(world.positions[u] == g for u, g in goals.items()),
            30,
            what="every unit at its goal",
        )
        await async_wait_for(
            lambda: (s := op.last_state("unit1")) and s.direction == "-" and device.leds == Leds(),
            5,
            what="unit1 and the device at rest",
        )
        check_intentions("unit1", op.display("unit1", since))
        # From the idle state before the goals (what the device showed since it came online):
        # under load the first state after the mark may already show a move.
        unit_shows = dedup([Leds(), *(leds for _, leds in op.display("unit1", since))])
        # What the unit showed, the device showed, in the same order, nothing else in between.
        assert_follows(dedup(shown), unit_shows)
        assert len(unit_shows) >= 4 and {"E", "S"} <= {d for x in unit_shows for d in lit(x)}

        # 2. Its stop key halts every unit while they drive back to where they started.
        for unit in units:
            await asyncio.to_thread(send_goal, op, unit, starts[unit])
        moved = dict(world.moves)
        await async_wait_for(
            lambda: all(world.moves[u] >= moved[u] + 2 for u in units), 15, what="under way"
        )
        device.press()
        assert device.leds == ALL  # the press shows at once, before the broker confirms it
        await async_wait_for(
            lambda: all((s := op.last_state(u)) and s.estop for u in units),
            5,
            what="all units stopped",
        )
        first_stopped = {u: next(s for s in op.states(u) if s.estop) for u in units}
        held = dict(world.positions)
        moves = dict(world.moves)
        marks = {u: step_of(op, u) for u in units}
        await async_wait_for(lambda: stepped_past(op, marks, 5), 5, what="five steps stopped")
        assert world.positions == held and world.moves == moves
        for unit in units:
            # Halted within one step: where it stood when it said stopped, it still stands.
            assert Cell(*first_stopped[unit].position) == held[unit]
            last = op.last_state(unit)
            assert last is not None and last.status == "stopped" and lit(last.leds) == set("NESW")
        # Visible where the dashboard looks: the retained estop topic and the coordinator status.
        # The probe hears the device on its own connection: the signal may come after the states.
        signals = await async_wait_for(op.estop_signals, 5, what="the stop on the estop topic")
        engaged = signals[-1]
        assert (engaged.engaged, engaged.by, engaged.reason) == (True, "dev-accept", "button")
        await async_wait_for(lambda: coordinator_estop(op) is True, 5, what="coordinator stop")
        late = await asyncio.to_thread(probe_factory)  # a dashboard opened now
        await asyncio.to_thread(late.subscribe, topics.fleet("estop"), 1)
        seen = await async_wait_for(lambda: late.received(topics.fleet("estop")), what="retained")
        assert seen[0].retain and decode_estop(seen[0].payload) == engaged
        await async_wait_for(lambda: not device.core.pending_stop, what="stop confirmed")
        assert device.leds == ALL
        assert sum(s.engaged for s in op.estop_signals()) == 1  # one press, one stop

        # 3. Only a deliberate release lets them go on; they all get home, nobody collided.
        await asyncio.to_thread(op.release, RELEASE_REASON)
        await async_wait_for(lambda: device.leds != ALL, 5, what="device shows direction again")
        await async_wait_for(
            lambda: all(world.positions[u] == starts[u] for u in units),
            30,
            what="every unit back at its start",
        )
        await async_wait_for(lambda: device.leds == Leds(), 5, what="device at rest")
        assert world.collisions == 0
        await async_wait_for(lambda: coordinator_estop(op) is False, 5, what="coordinator release")
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)


# -- test_06, seen by a person: the dashboard in a real browser ---------------------------------
# Sync and last in this module: Playwright keeps an event loop on the thread while it is open.


class DeviceService:
    """The virtual device as a ServiceThread service: ready once online; press from any thread."""

    def __init__(self, device: DeviceShell) -> None:
        self.device = device
        self.ready = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        device.on_change = lambda logic: self.ready.set() if logic.online else None

    async def run(self, shutdown: asyncio.Event) -> None:
        """Run the device until `stop` is set."""
        self._loop = asyncio.get_running_loop()
        await self.device.run(shutdown)

    def press(self) -> None:
        """Press the stop key (the device's loop does the work)."""
        assert self._loop is not None
        self._loop.call_soon_threadsafe(self.device.press)


@pytest.mark.timeout(150)  # its waits add up to more than 60 s: a slow run fails on the late one
def test_06_the_device_stop_shows_on_the_dashboard_and_its_release_resumes_the_fleet(
    run_system: RunSystem,
    probe_factory: Callable[..., MqttProbe],
    open_dashboard: Callable[..., Any],
    broker: BrokerThread,
    topics: Topics,
    root: str,
) -> None:
    from playwright.sync_api import expect

    from gridfleet.scenario import load_scenario

    scenario = load_scenario(MAPS / "playfield.toml")
    op = OperatorPeer(probe_factory(), topics, OPERATOR)
    _, fleet = run_system(scenario, step_s=STEP_S)
    world = world_of(fleet)
    virtual = DeviceShell(broker.url, "unit2", root, device_id="dev-dash")
    service = DeviceService(virtual)
    with ServiceThread(lambda: service, "virtual-device"):
        dash = open_dashboard(grid=scenario.grid)
        send_goal(op, "unit2", Cell(0, 9))
        wait_for(lambda: world.moves["unit2"] >= 2, 15, what="unit2 under way")
        service.press()
        expect(dash.page.locator("body")).to_have_attribute("data-estop", "engaged")
        expect(dash.page.locator("#estop-banner")).to_contain_text("engaged by dev-dash")
        wait_for(lambda: (s := op.last_state("unit2")) and s.estop, 5, what="unit2 stopped")
        held = world.positions["unit2"]
        mark = {"unit2": step_of(op, "unit2")}
        wait_for(lambda: stepped_past(op, mark, 5), 5, what="five steps stopped")
        assert world.positions["unit2"] == held
        # The operator's deliberate release, with the dashboard's own control.
        dash.hold_release()
        expect(dash.page.locator("body")).to_have_attribute("data-estop", "released")
        released = op.estop_signals()[-1]
        assert not released.engaged and released.by == dash.client_id  # the page's own id
        wait_for(lambda: not virtual.core.estop_engaged, 5, what="device sees the release")
        wait_for(lambda: world.positions["unit2"] == Cell(0, 9), 30, what="unit2 at its goal")
        assert world.collisions == 0
        assert dash.errors == []
