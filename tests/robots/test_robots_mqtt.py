"""Simulated units on a real broker: the tests play the coordinator with a DispatchPeer."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path

import aiomqtt
import pytest

from gridfleet.grid import Cell, Direction
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    Connection,
    Leds,
    Order,
    Topics,
    decode,
    encode,
)
from gridfleet.robots.fleet import Fleet
from gridfleet.robots.unit import Mode
from gridfleet.scenario import Scenario, load_scenario
from gridfleet.system.broker_thread import BrokerThread

from support.fleet_peer import leds_for
from support.peers import DispatchPeer
from support.probe import MqttProbe
from support.wait import async_wait_for

STEP = 0.02
Probe = Callable[..., MqttProbe]


def scenario(
    tmp_path: Path,
    rows: list[str],
    units: dict[str, tuple[int, int]],
    hidden: list[tuple[int, int]] = (),  # type: ignore[assignment]
) -> Scenario:
    """A scenario file of `rows` (`.` free, `@` obstacle) with units and hidden obstacles."""
    (tmp_path / "m.map").write_text(
        f"type octile\nheight {len(rows)}\nwidth {len(rows[0])}\nmap\n" + "\n".join(rows) + "\n"
    )
    body = f'map = "m.map"\nhidden_obstacles = {[list(h) for h in hidden]}\n'
    for uid, (x, y) in units.items():
        body += f'[[units]]\nid = "{uid}"\nstart = [{x}, {y}]\ncapacity = 5.0\n'
    (tmp_path / "s.toml").write_text(body)
    return load_scenario(tmp_path / "s.toml")


@asynccontextmanager
async def running(
    sc: Scenario,
    url: str,
    root: str,
    mode: Mode = "coordinated",
    coordinator: DispatchPeer | None = None,
    **kw: object,
) -> AsyncIterator[Fleet]:
    """A fleet running in this event loop until the block ends; then it stops cleanly.

    With `coordinator`, it also waits until every unit has read that peer's status.
    """
    fleet = Fleet(sc, url, root=root, step=kw.pop("step", STEP), mode=mode, **kw)  # type: ignore[arg-type]
    stop = asyncio.Event()
    task = asyncio.create_task(fleet.run(stop))
    try:
        await asyncio.wait_for(fleet.ready.wait(), 10)
        # Wait until each unit has read the (absent) retained emergency stop and can move.
        await async_wait_for(
            lambda: all(lg.estop_known for lg in fleet.logic.values()), what="units ready"
        )
        if coordinator is not None and coordinator.step_period_s is not None:
            period = coordinator.step_period_s
            await async_wait_for(
                lambda: all(lg.coordinator_step_s == period for lg in fleet.logic.values()),
                what="the coordinator's status read",
            )
        yield fleet
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)


async def steps(fleet: Fleet, unit: str, n: int) -> None:
    """Wait until `unit` has made `n` more steps (the way to watch something not happen)."""
    target = fleet.logic[unit].step + n
    await async_wait_for(lambda: fleet.logic[unit].step >= target, what=f"{n} steps of {unit}")


OPEN = [".....", ".....", "....."]


async def test_unit_moves_and_its_published_pose_and_leds_follow(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, OPEN, {"u1": (0, 1)})
    c = DispatchPeer(probe_factory(), topics)
    async with running(sc, broker.url, root, coordinator=c) as fleet:
        c.order("u1", "o1", 1, [(1, 1), (2, 1), (2, 2), (3, 2)], planned=[(4, 2)])
        await c.until_state("u1", lambda s: s.position == Cell(3, 2) and s.direction == "-")
        await steps(fleet, "u1", 3)
        assert fleet.world.positions["u1"] == Cell(3, 2)  # never drives the planned rest
        assert fleet.world.moves["u1"] == 4 and fleet.world.collisions == 0
    states = c.states("u1")
    path = [s.position for s in states]
    assert [p for i, p in enumerate(path) if i == 0 or p != path[i - 1]] == [
        Cell(0, 1),
        Cell(1, 1),
        Cell(2, 1),
        Cell(2, 2),
        Cell(3, 2),
    ]
    # Each move was shown before it was made: the direction named it before the state that
    # reports the move (an order's first move is shown at once, between steps; protocol §4.6).
    shown = Leds()
    at = Cell(0, 1)
    for s, leds in c.display("u1"):
        if s is not None and s.position != at:
            made = at.direction_to(s.position)
            assert made is not None and shown == leds_for(made), f"{shown} before a move {made}"
            at = s.position
        if s is not None:  # the LEDs say the direction
            assert s.leds == leds_for(None if s.direction == "-" else Direction(s.direction))
        shown = leds
    directions = c.directions("u1")
    assert Direction.E in directions and Direction.S in directions and directions[-1] is None


async def test_sensors_see_every_kind_in_all_four_directions(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, ["@..", "..."], {"u1": (1, 0), "u2": (1, 1)}, hidden=[(2, 0)])
    c = DispatchPeer(probe_factory(), topics)
    async with running(sc, broker.url, root, coordinator=c):
        s = await c.until_state("u1", lambda s: s.step > 0)
        assert s.sensors.model_dump() == {
            "N": "wall",
            "E": "obstacle",
            "S": "unit",
            "W": "obstacle",
        }
        s2 = await c.until_state("u2", lambda s: s.step > 0)
        assert s2.sensors.model_dump() == {"N": "unit", "E": "free", "S": "wall", "W": "free"}
    reported = [o for s in c.states("u1") for o in s.obstacles]
    assert reported == [Cell(2, 0)]  # the hidden one; the map's `@` and the unit are not reported
    assert all(s.obstacles == [] for s in c.states("u2"))


async def test_hidden_obstacle_in_the_way_is_reported_once_and_never_a_unit(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, OPEN, {"u1": (0, 1), "u2": (1, 0)}, hidden=[(3, 1)])
    c = DispatchPeer(probe_factory(), topics)
    async with running(sc, broker.url, root, coordinator=c) as fleet:
        c.order("u1", "o1", 1, [(1, 1), (2, 1), (3, 1), (4, 1)])
        s = await c.until_state("u1", lambda s: s.status == "waiting" and s.position == Cell(2, 1))
        assert s.wait_reason is not None and "obstacle" in s.wait_reason
        await steps(fleet, "u1", 5)
        assert fleet.world.positions["u1"] == Cell(2, 1)
        assert (fleet.world.collisions, fleet.world.prevented) == (0, 0)
    reported = [o for s in c.states("u1") for o in s.obstacles]
    assert reported == [Cell(3, 1)]
    assert any(s.sensors.N == "unit" for s in c.states("u1"))  # it passed u2 and saw a unit


async def test_unit_refuses_unreleased_and_occupied_squares(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, OPEN, {"u1": (0, 1), "u2": (2, 1)})
    c = DispatchPeer(probe_factory(), topics)
    async with running(sc, broker.url, root, coordinator=c) as fleet:
        # u2's square released to u1 by mistake: u1's own sensor sees a unit and it waits.
        c.order("u1", "o1", 1, [(1, 1), (2, 1), (3, 1)])
        s = await c.until_state("u1", lambda s: s.position == Cell(1, 1) and s.status == "waiting")
        assert s.wait_reason is not None and "another unit" in s.wait_reason
        await steps(fleet, "u1", 5)
        assert fleet.world.positions == {"u1": Cell(1, 1), "u2": Cell(2, 1)}
        # A halt order releases nothing: the unit stays.
        c.order("u1", "o2", 1, [])
        await c.until_state("u1", lambda s: s.order_id == "o2" and s.released == [])
        await steps(fleet, "u1", 5)
        assert fleet.world.positions["u1"] == Cell(1, 1)
        assert (fleet.world.collisions, fleet.world.prevented) == (0, 0)


async def test_emergency_stop_halts_all_units_within_one_step_until_released(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    rows = ["." * 30, "." * 30, "." * 30]
    sc = scenario(tmp_path, rows, {"u1": (0, 0), "u2": (0, 2)})
    c = DispatchPeer(probe_factory(), topics)
    async with running(sc, broker.url, root, coordinator=c) as fleet:
        for uid, y in (("u1", 0), ("u2", 2)):
            c.order(uid, "o1", 1, [(x, y) for x in range(1, 30)])
        await async_wait_for(lambda: all(fleet.world.moves[u] >= 2 for u in ("u1", "u2")))
        c.estop(True)
        first = {u: await c.until_state(u, lambda s: s.estop) for u in ("u1", "u2")}
        for u in ("u1", "u2"):
            await steps(fleet, u, 8)
            # At most the step already under way when the message came: nothing after.
            assert fleet.world.positions[u] == Cell(*first[u].position)
            s = c.states(u)[-1]
            assert s.status == "stopped" and all(s.leds.model_dump().values())
        # Orders during the stop change nothing; a malformed payload never releases.
        c.order("u1", "o2", 1, [(first["u1"].position[0] + 1, 0)])
        c.estop(False, payload=b"releasd|tester|typo")
        await async_wait_for(lambda: any("estop" in e.reason for e in c.errors()))
        await steps(fleet, "u1", 8)
        assert fleet.world.positions["u1"] == Cell(*first["u1"].position)
        assert fleet.logic["u1"].estop
        c.estop(False)
        await async_wait_for(lambda: not any(lg.estop for lg in fleet.logic.values()))
        x = first["u1"].position[0]
        c.order("u1", "o3", 1, [(x + 1, 0)])
        await c.until_state("u1", lambda s: s.position == Cell(x + 1, 0))
        assert fleet.world.collisions == 0


async def test_bad_orders_are_refused_with_an_error_and_change_nothing(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, [".....", ".@...", "....."], {"u1": (0, 1)})
    c = DispatchPeer(probe_factory(), topics)
    async with running(sc, broker.url, root, coordinator=c) as fleet:
        c.order("u1", "good", 1, [(0, 0)])
        await c.until_state("u1", lambda s: s.position == Cell(0, 0))
        c.order("u1", "good", 2, [])
        await c.until_state("u1", lambda s: s.order_update_id == 2)
        bad = [
            b"{not json",
            b'{"header": ' + b" " * 20000 + b"}",
            b'{"order_id": "x"}',
            encode(Order(header=c.stamp("order"), order_id="x", update_id=1, released=[(0, 4000)])),
            encode(Order(header=c.stamp("order"), order_id="x", update_id=1, released=[(1, 1)])),
            encode(Order(header=c.stamp("order"), order_id="x", update_id=1, released=[(2, 0)])),
            encode(
                Order(header=c.stamp("order"), order_id="x", update_id=1, released=[(1, 0), (3, 0)])
            ),
        ]
        for payload in bad:
            c.raw_order("u1", payload)
        await async_wait_for(lambda: len(c.errors()) >= len(bad), what="one error per bad order")
        await async_wait_for(
            lambda: sum(len(s.errors) for s in c.states("u1")) >= len(bad), what="state errors"
        )
        errors = [e.code for s in c.states("u1") for e in s.errors]
        assert errors == ["bad_order"] * len(bad)
        reports = c.errors()
        assert all(r.topic == topics.unit("order", "u1") for r in reports)
        assert "exceeds" in reports[1].reason and "malformed JSON" in reports[0].reason
        await steps(fleet, "u1", 5)
        lg = fleet.logic["u1"]
        assert (lg.position, lg.order_id, lg.order_update_id, lg.released) == (
            Cell(0, 0),
            "good",
            2,
            [],
        )
        assert fleet.world.moves["u1"] == 1


@pytest.mark.every_broker  # a clean stop's offline, not the will
async def test_connection_online_then_offline_on_a_clean_stop(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, OPEN, {"u1": (0, 1), "u2": (4, 1)})
    c = DispatchPeer(probe_factory(), topics)
    factsheets = topics.unit("factsheet", "u1")
    c.probe.subscribe(factsheets)
    async with running(sc, broker.url, root, coordinator=c):
        await async_wait_for(
            lambda: c.connections("u1") == ["online"] and c.connections("u2") == ["online"]
        )
        await async_wait_for(lambda: c.probe.received(factsheets))
    await async_wait_for(
        lambda: c.connections("u1")[-1:] == ["offline"] and c.connections("u2")[-1:] == ["offline"]
    )
    assert [m.retain for m in c.probe.received(factsheets)] == [False]  # live delivery


@pytest.mark.every_broker  # the broker sends the will
async def test_dropped_connection_shows_broken_and_the_unit_holds_then_reconnects(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, ["." * 20], {"u1": (0, 0)})
    # No announced step: the unit's own hold timeout (0.5 s) has passed when it reconnects.
    c = DispatchPeer(probe_factory(), topics, step_period_s=None)
    async with running(sc, broker.url, root, step=0.05, reconnect_s=1.0) as fleet:
        runner = fleet.shells["u1"]
        c.order("u1", "o1", 1, [(x, 0) for x in range(1, 20)])
        await async_wait_for(lambda: fleet.world.moves["u1"] >= 1)
        runner.drop_connection()
        await async_wait_for(lambda: "broken" in c.connections("u1"), what="the last will")
        # The broker may publish the will before the unit notices the cut (at its next tick at
        # the latest); from then on it holds.
        await async_wait_for(lambda: fleet.logic["u1"].status == "holding", what="holding")
        held = fleet.world.positions["u1"]
        await async_wait_for(lambda: runner.connects == 2, what="the reconnect")
        assert fleet.world.positions["u1"] == held
        await async_wait_for(lambda: c.connections("u1")[-1] == "online")
        await steps(fleet, "u1", 4)
        assert (
            fleet.world.positions["u1"] == held
        )  # the released rest was dropped: no order, no move
        c.order("u1", "o2", 1, [(held.x + 1, 0)])
        await c.until_state("u1", lambda s: s.position == Cell(held.x + 1, 0))


@pytest.mark.every_broker  # the broker takes over the session
async def test_a_send_failing_late_on_the_dropped_connection_leaves_the_new_one_alone(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    # A QoS 1 send on a cut connection fails only when its acknowledgement times out, which can
    # be after the unit has reconnected; that failure must not take the new connection down.
    sc = scenario(tmp_path, ["." * 20], {"u1": (0, 0)})
    c = DispatchPeer(probe_factory(), topics)
    async with running(sc, broker.url, root, coordinator=c, step=0.05, reconnect_s=0.2) as fleet:
        runner = fleet.shells["u1"]
        old = runner.endpoint._client  # the live connection, to make one send on it hang
        assert old is not None
        timed_out = asyncio.Event()

        async def publish_never_acknowledged(*args: object, **kwargs: object) -> None:
            await timed_out.wait()
            raise aiomqtt.MqttError("Operation timed out")

        old.publish = publish_never_acknowledged  # type: ignore[method-assign]
        late = Outbound(topics.unit("state", "u1"), b"{}", 0, True)
        pending = asyncio.ensure_future(runner.endpoint.publish(late))
        runner.drop_connection()
        await async_wait_for(lambda: runner.connects == 2 and runner.online.is_set())
        timed_out.set()
        await pending
        assert runner.endpoint.connected and fleet.logic["u1"].connected
        c.order("u1", "o1", 1, [(1, 0)])
        await c.until_state("u1", lambda s: s.position == Cell(1, 0))


@pytest.mark.every_broker  # a broker restarted
async def test_units_reconnect_after_a_broker_restart(
    tmp_path: Path, fresh_broker: BrokerThread, root: str, topics: Topics
) -> None:
    sc = scenario(tmp_path, OPEN, {"u1": (0, 1)})
    async with running(sc, fresh_broker.url, root, reconnect_s=0.05) as fleet:
        runner = fleet.shells["u1"]
        fresh_broker.stop()
        await async_wait_for(lambda: fleet.logic["u1"].status == "holding", what="holding")
        fresh_broker.start()
        await async_wait_for(lambda: runner.connects >= 2, what="reconnect")
        with MqttProbe(fresh_broker.url) as probe:
            probe.subscribe(topics.unit("connection", "u1"))
            probe.subscribe(topics.unit("factsheet", "u1"))
            await async_wait_for(lambda: probe.received(topics.unit("factsheet", "u1")))
            seen = probe.received(topics.unit("connection", "u1"))
            assert decode(Connection, seen[-1].payload).state == "online"


async def test_standalone_units_cross_the_playfield_without_collisions(
    broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe, playfield: Path
) -> None:
    sc = load_scenario(playfield)
    operator = DispatchPeer(probe_factory(), topics, step_period_s=None, sender="operator")
    goals = {"unit1": Cell(9, 9), "unit2": Cell(0, 9), "unit3": Cell(9, 0), "unit4": Cell(0, 0)}
    async with running(sc, broker.url, root, mode="standalone") as fleet:
        for uid, target in goals.items():
            operator.goal(uid, target)
        await async_wait_for(
            lambda: all(fleet.world.positions[u] == g for u, g in goals.items()),
            timeout=30,
            what="every unit at its goal",
        )
        assert fleet.world.collisions == 0
        print(f"prevented moves: {fleet.world.prevented}, moves: {fleet.world.moves}")
        await async_wait_for(lambda: all(lg.status == "idle" for lg in fleet.logic.values()))


async def test_units_in_another_process_are_seen_through_their_state(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, OPEN, {"u1": (0, 1), "u2": (2, 1)})
    c = DispatchPeer(probe_factory(), topics)
    async with (
        running(sc, broker.url, root, coordinator=c, units=["u1"]) as here,
        running(sc, broker.url, root, coordinator=c, units=["u2"]) as there,
    ):
        assert set(here.shells) == {"u1"} and set(there.shells) == {"u2"}
        c.order("u2", "o1", 1, [(2, 2), (3, 2)])
        await async_wait_for(lambda: here.world.positions["u2"] == Cell(3, 2), what="u2 seen moved")
        c.order("u2", "o1", 2, [(3, 1)])
        await async_wait_for(lambda: here.world.positions["u2"] == Cell(3, 1))
        # u2 (simulated elsewhere) stands on a square released to u1: u1's sensor sees a unit.
        c.order("u1", "o1", 1, [(1, 1), (2, 1), (3, 1), (4, 1)])
        s = await c.until_state("u1", lambda s: s.position == Cell(2, 1) and s.status == "waiting")
        assert s.sensors.E == "unit" and s.obstacles == []
        await steps(here, "u1", 5)
        assert here.world.positions["u1"] == Cell(2, 1)
        assert here.world.collisions == 0 and there.world.collisions == 0
        assert here.world.moves["u1"] == 2 and there.world.moves["u2"] == 3


async def test_malformed_goal_and_estop_payloads_are_refused_and_reported(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, [".....", ".@..."], {"u1": (0, 0)})
    c = DispatchPeer(probe_factory(), topics, sender="operator")
    async with running(sc, broker.url, root, mode="standalone") as fleet:
        goal_topic = topics.unit("goal", "u1")
        c.raw_goal("u1", b'{"target": [1, 1]}')  # no header
        c.goal("u1", Cell(1, 1))  # a wall
        c.goal("u1", Cell(7, 0))  # off the map
        c.estop(True, payload=b"maybe|operator|")
        await async_wait_for(lambda: len(c.errors()) >= 4, what="four error reports")
        assert [e.topic for e in c.errors()].count(goal_topic) == 3
        await steps(fleet, "u1", 3)
        lg = fleet.logic["u1"]
        assert lg.goal is None and not lg.estop and fleet.world.moves["u1"] == 0
        c.goal("u1", Cell(4, 1))
        s = await c.until_state("u1", lambda s: s.position == Cell(4, 1) and s.status == "idle")
        assert s.goal == Cell(4, 1) and s.mode == "standalone"


async def test_unit_holds_without_orders_and_resumes_when_they_come_back(
    tmp_path: Path, broker: BrokerThread, root: str, topics: Topics, probe_factory: Probe
) -> None:
    sc = scenario(tmp_path, OPEN, {"u1": (0, 1)})
    c = DispatchPeer(probe_factory(), topics, step_period_s=0.3)
    async with running(sc, broker.url, root, coordinator=c) as fleet:
        lg = fleet.logic["u1"]
        assert lg.hold_timeout_s == 3 * 0.3
        c.order("u1", "o1", 1, [(1, 1)])
        await c.until_state("u1", lambda s: s.position == Cell(1, 1))
        s = await c.until_state(
            "u1", lambda s: s.status == "holding" and s.position == Cell(1, 1), timeout=5
        )
        assert s.wait_reason is not None and "no order" in s.wait_reason
        c.order("u1", "o1", 2, [(2, 1)])
        s = await c.until_state("u1", lambda s: s.position == Cell(2, 1))
        assert fleet.world.moves["u1"] == 2
