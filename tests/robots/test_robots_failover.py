"""A unit across a new connection (a broker's death, a failover): it drives nothing released before.

protocol.md §5.1, "Across a broker's death": a broker failed over to may never have seen the stop
engaged, and finds the unit no retained latch; the unit must not then drive what remains of its
last window. It moves again only on an order (or, standalone, a goal) heard on the new connection.
Exact messages, as tests/robots/test_robots_effects.py pins them.
"""

from __future__ import annotations

from test_robots_effects import (
    COORDINATOR,
    FREE,
    LED_E,
    ROOT,
    allow,
    direction,
    make,
    order_bytes,
    ready,
    refuse,
    state,
)

from gridfleet.grid import Cell, Direction
from gridfleet.protocol import Goal, encode
from gridfleet.robots.core import UnitCore

from support.effects import published

ORDER = ROOT + "units/u1/order"
ESTOP = ROOT + "fleet/estop"
O1 = {"order_id": "o1", "order_update_id": 1}


def driving() -> UnitCore:
    """A ready unit released three squares east at 0.25, one of them driven at 0.3."""
    core = ready()
    core.on_message(ORDER, order_bytes("o1", 1, [Cell(1, 1), Cell(2, 1), Cell(3, 1)]), 0.25)
    core.tick(lambda: FREE, allow, 0.3)
    assert core.logic.position == Cell(1, 1) and core.logic.released == [Cell(2, 1), Cell(3, 1)]
    return core


def test_a_unit_back_within_its_hold_time_on_a_broker_with_no_stop_drives_nothing_from_before() -> (
    None
):
    core = driving()
    core.on_disconnect(0.35)
    assert core.logic.released == []  # dropped with the connection, not after the hold time
    on = published(core.on_connect(0.4), ROOT)[2:]  # back 0.05 s later: well within 0.5 s
    assert on == [
        state(
            3,
            step=2,
            position=[1, 1],
            status="holding",
            wait_reason="waiting to read the emergency stop",
            **O1,
        ),
        direction("-"),
    ]
    # The broker had no retained stop (it never saw it): the stop counts as released, and still
    # the unit does not move, for none of what it was released before is left.
    for at in (0.6, 0.65, 0.7):  # its last order at 0.25, its hold time 0.5 s: not holding yet
        core.tick(lambda: FREE, refuse, at)
    assert (core.logic.position, core.logic.status) == (Cell(1, 1), "idle")
    # The coordinator's next order on this connection (its heartbeat: a new update) drives it.
    core.on_message(ORDER, order_bytes("o1", 2, [Cell(2, 1), Cell(3, 1)]), 0.72)
    assert published(core.tick(lambda: FREE, allow, 0.75), ROOT) == [
        state(
            5,
            step=6,
            position=[2, 1],
            direction="E",
            status="moving",
            leds=LED_E,
            released=[[3, 1]],
            order_id="o1",
            order_update_id=2,
        ),
    ]


def test_the_same_order_again_after_a_reconnect_releases_nothing() -> None:
    core = driving()
    core.on_disconnect(0.35)
    core.on_connect(0.4)
    # A copy of the order it had (same id and update): stale, so it changes nothing (rule 1).
    core.on_message(ORDER, order_bytes("o1", 1, [Cell(1, 1), Cell(2, 1), Cell(3, 1)]), 0.45)
    for at in (0.6, 0.7):
        core.tick(lambda: FREE, refuse, at)
    assert core.logic.position == Cell(1, 1) and core.logic.released == []


def test_an_order_heard_before_the_retained_stop_is_dropped_by_it() -> None:
    core = driving()
    core.on_disconnect(0.35)
    core.on_connect(0.4)
    core.on_message(ORDER, order_bytes("o1", 2, [Cell(2, 1)]), 0.41)  # before the latch
    core.on_message(ESTOP, b"engaged|dashboard|stop", 0.42)
    for at in (0.6, 0.7):
        core.tick(lambda: FREE, refuse, at)
    assert (core.logic.status, core.logic.released) == ("stopped", [])


def test_a_standalone_unit_forgets_its_goal_with_the_connection_and_keeps_it_before_the_first() -> (
    None
):
    core = make("standalone")
    goal = encode(Goal(header=COORDINATOR("goal"), target=Cell(4, 1)))
    core.on_message(ROOT + "units/u1/goal", goal, 0.0)
    core.on_connect(0.0)  # a goal given before the first connection is kept
    core.tick(lambda: FREE, refuse, 0.2)  # showing its direction first
    core.tick(lambda: FREE, allow, 0.3)
    assert core.logic.position == Cell(1, 1) and core.logic.goal == Cell(4, 1)
    core.on_disconnect(0.35)
    assert core.logic.goal is None
    core.on_connect(0.4)
    for at in (0.6, 0.7, 0.8):
        core.tick(lambda: FREE, refuse, at)
    assert (core.logic.position, core.logic.status) == (Cell(1, 1), "idle")
    core.on_message(ROOT + "units/u1/goal", goal, 0.85)  # an operator sends it again
    core.tick(lambda: FREE, allow, 0.9)
    assert core.logic.direction is Direction.E or core.logic.position == Cell(2, 1)
