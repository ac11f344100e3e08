"""Exactly what a unit publishes for each input: its core fed with a fixed clock, no broker.

Every test feeds `UnitCore` one input (a connect, a tick, a message on a topic the unit follows)
and asserts the whole list it returns: topic, parsed payload, QoS and retain flag, in order.
"""

from __future__ import annotations

from datetime import timedelta
from typing import Any

import pytest

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol import (
    CoordinatorStatus,
    Goal,
    Header,
    Order,
    Topics,
    encode,
)
from gridfleet.protocol.messages import EnergyModel, SensorReading
from gridfleet.robots.battery import Battery
from gridfleet.robots.core import UnitCore
from gridfleet.robots.unit import Mode, UnitLogic

from support.effects import FIXED, Published, header, header_json, published, stamper

ROOT = "gf/v1/"
OPEN = (".....", ".....", ".....")
FREE: dict[Direction, SensorReading] = dict.fromkeys(Direction, "free")
AT_WEST_EDGE: dict[Direction, SensorReading] = {**FREE, Direction.W: "wall"}
LEDS_OFF = dict.fromkeys("NESW", False)
LEDS_ALL = dict.fromkeys("NESW", True)
LED_E = {**LEDS_OFF, "E": True}
COORDINATOR = stamper("coordinator")


def make(mode: Mode = "coordinated", rows: tuple[str, ...] = OPEN) -> UnitCore:
    """Unit u1 on (0, 1) of `rows`, its headers stamped at FIXED; started at time 0."""
    logic = UnitLogic("u1", GridMap.from_rows(rows), Cell(0, 1), 5.0, 0.1, mode=mode)
    core = UnitCore(logic, Topics("gf"), color="#d32f2f", stamp=stamper("u1"))
    core.start(0.0)
    return core


def ready(mode: Mode = "coordinated", rows: tuple[str, ...] = OPEN) -> UnitCore:
    """Connected at 0 and one step made at 0.2, once the retained stop can have arrived.

    It has then sent state seq 0 and 1 and direction `-`; its step counter is 1.
    """
    core = make(mode, rows)
    core.will()
    core.on_connect(0.0)
    core.tick(lambda: FREE, refuse, 0.2)
    assert core.logic.estop_known and core.logic.status == "idle"
    return core


def refuse(direction: Direction) -> bool:
    """The world's answer to a move a test does not expect."""
    raise AssertionError(f"unexpected move {direction.value}")


def allow(direction: Direction) -> bool:
    """The world lets every move happen."""
    return True


def state(seq: int, **fields: Any) -> Published:
    """u1's state message: the idle unit on (0, 1) with `fields` changed."""
    payload = {
        "header": header_json("u1", seq),
        "step": 1,
        "position": [0, 1],
        "direction": "-",
        "status": "idle",
        "wait_reason": None,
        "mode": "coordinated",
        "job_id": None,
        "load_kg": 0.0,
        "leds": LEDS_OFF,
        "sensors": {"N": "free", "E": "free", "S": "free", "W": "free"},
        "obstacles": [],
        "order_id": None,
        "order_update_id": 0,
        "released": [],
        "goal": None,
        "estop": False,
        "errors": [],
        "battery_pct": None,
        "charging": False,
    }
    assert set(fields) <= set(payload), set(fields) - set(payload)
    return ("units/u1/state", payload | fields, 0, True)


def direction(letter: str) -> Published:
    return ("units/u1/direction", letter, 0, True)


def error(seq: int, topic: str, reason: str) -> Published:
    payload = {
        "header": header_json("u1", seq),
        "topic": ROOT + topic,
        "reason": reason,
        "request_id": None,
    }
    return ("errors", payload, 1, False)


def order_bytes(oid: str, update: int, released: list[Cell]) -> bytes:
    return encode(
        Order(header=COORDINATOR("order"), order_id=oid, update_id=update, released=released)
    )


# ---- connect, ticks, disconnect, goodbye ------------------------------------------------------


def test_connect_says_online_then_the_factsheet_then_a_state_holding_for_the_stop() -> None:
    core = make()
    assert published([core.will()], ROOT) == [
        ("units/u1/connection", {"header": header_json("u1", 0), "state": "broken"}, 1, True)
    ]
    factsheet = {
        "header": header_json("u1", 0),
        "capacity_kg": 5.0,
        "step_period_s": 0.1,
        "sensors": ["N", "E", "S", "W"],
        "color": "#d32f2f",
        "model": "gridfleet-sim",
        "map_id": core.logic.grid.map_id(),  # the coordinator ignores units of another map
        "energy": None,  # no battery: it never runs down
    }
    assert published(core.on_connect(0.0), ROOT) == [
        ("units/u1/connection", {"header": header_json("u1", 1), "state": "online"}, 1, True),
        ("units/u1/factsheet", factsheet, 1, True),
        state(0, step=0, status="holding", wait_reason="waiting to read the emergency stop"),
        direction("-"),
    ]


def test_subscriptions_follow_the_mode() -> None:
    # Every one at QoS 0, whatever its topic's QoS (protocol.md §2).
    stop = [("gf/v1/fleet/estop", 0), ("gf/v1/units/+/stop", 0), ("gf/v1/devices/+/stop", 0)]
    assert make().subscriptions() == [
        *stop,
        ("gf/v1/units/u1/order", 0),
        ("gf/v1/coordinator/status", 0),
        ("gf/v1/units/u1/connection", 0),  # its own, set right (protocol.md §4.1)
    ]
    assert make("standalone").subscriptions(watch_peers=True) == [
        *stop,
        ("gf/v1/units/u1/goal", 0),
        ("gf/v1/units/u1/connection", 0),
        ("gf/v1/units/+/state", 0),
    ]


def test_a_tick_holds_until_the_retained_stop_can_have_arrived_then_the_unit_is_idle() -> None:
    core = make()
    core.on_connect(0.0)
    holding = {"status": "holding", "wait_reason": "waiting to read the emergency stop"}
    sensors = {"N": "free", "E": "free", "S": "free", "W": "wall"}
    # The stop can have arrived 0.2 s after connecting (min(1, max(0.2, step 0.1)), §5.1).
    assert published(core.tick(lambda: AT_WEST_EDGE, refuse, 0.19), ROOT) == [
        state(1, step=1, sensors=sensors, **holding)
    ]
    assert published(core.tick(lambda: AT_WEST_EDGE, refuse, 0.2), ROOT) == [
        state(2, step=2, sensors=sensors)
    ]


def test_a_tick_moves_into_the_released_square_shown_before() -> None:
    core = ready()
    core.on_message(ROOT + "units/u1/order", order_bytes("o1", 1, [Cell(1, 1), Cell(2, 1)]), 0.25)
    order = {"order_id": "o1", "order_update_id": 1}
    assert published(core.tick(lambda: FREE, allow, 0.3), ROOT) == [
        state(
            2,
            step=2,
            position=[1, 1],
            direction="E",
            status="moving",
            leds=LED_E,
            released=[[2, 1]],
            **order,
        )
    ]
    assert published(core.tick(lambda: FREE, allow, 0.4), ROOT) == [
        state(3, step=3, position=[2, 1], status="moving", **order),
        direction("-"),
    ]


def test_a_lost_broker_sends_nothing_and_the_next_connection_reports_what_waited() -> None:
    core = ready()
    core.on_disconnect(0.3)
    east_obstacle = {**FREE, Direction.E: "obstacle"}
    assert core.tick(lambda: east_obstacle, refuse, 0.4) == []
    assert (core.logic.status, core.logic.wait_reason) == (
        "holding",
        "lost the broker; reconnecting",
    )
    sensors = {"N": "free", "E": "obstacle", "S": "free", "W": "free"}
    assert published(core.on_connect(0.5), ROOT)[2:] == [
        state(
            2,
            step=2,
            status="holding",
            wait_reason="waiting to read the emergency stop",
            sensors=sensors,
            obstacles=[[1, 1]],
        ),
        direction("-"),  # said again on every new connection
    ]


def test_a_unit_not_yet_connected_never_moves() -> None:
    core = make("standalone")
    core.on_message(
        ROOT + "units/u1/goal", encode(Goal(header=COORDINATOR("goal"), target=Cell(4, 1))), 0
    )
    assert core.tick(lambda: FREE, refuse, 0.1) == [] and core.tick(lambda: FREE, refuse, 5) == []
    assert core.logic.position == Cell(0, 1) and core.logic.status == "holding"


def test_a_clean_stop_says_offline() -> None:
    core = ready()
    assert published([core.offline()], ROOT) == [
        ("units/u1/connection", {"header": header_json("u1", 2), "state": "offline"}, 1, True)
    ]


# ---- orders -----------------------------------------------------------------------------------


def test_an_accepted_order_shows_its_first_move_at_once_and_the_next_state_acknowledges_it() -> (
    None
):
    # 100 units: a state answering each order made a burst after every coordinator step.
    core = ready()
    outs = core.on_message(
        ROOT + "units/u1/order", order_bytes("o1", 1, [Cell(1, 1), Cell(2, 1)]), 0.3
    )
    assert published(outs, ROOT) == [direction("E")]  # the LEDs: at once
    assert published(core.tick(lambda: FREE, allow, 0.4), ROOT) == [
        state(
            2,
            step=2,
            position=[1, 1],
            direction="E",
            status="moving",
            leds=LED_E,
            order_id="o1",
            order_update_id=1,
            released=[[2, 1]],
        )
    ]


def test_orders_are_told_with_the_next_state_not_at_once() -> None:
    core = ready()
    hold = order_bytes("o1", 1, [])
    assert core.on_message(ROOT + "units/u1/order", hold, 0.3) == []  # nothing to show yet
    assert published(core.tick(lambda: FREE, refuse, 0.35), ROOT) == [
        state(2, step=2, order_id="o1", order_update_id=1)  # a new order: news
    ]
    again = order_bytes("o1", 2, [])
    assert core.on_message(ROOT + "units/u1/order", again, 0.4) == []
    assert core.logic.order_update_id == 2  # taken all the same
    assert core.tick(lambda: FREE, refuse, 0.45) == []  # a heartbeat: nothing but its id
    moved = order_bytes("o1", 3, [Cell(1, 1)])
    core.on_message(ROOT + "units/u1/order", moved, 0.5)
    told = published(core.tick(lambda: FREE, lambda d: False, 0.55), ROOT)[0][1]
    assert (told["order_update_id"], told["released"]) == (3, [[1, 1]])


def test_a_unit_standing_still_is_heard_every_third_step() -> None:
    core = ready("standalone")  # its last state at step 1; no goal, so idle for good
    sent = [bool(core.tick(lambda: FREE, refuse, 0.2 + 0.1 * n)) for n in range(1, 10)]
    assert sent == [False, False, True] * 3
    # Anything new goes out at once: here a sensor reading.
    wall = {**FREE, Direction.N: "wall"}
    assert published(core.tick(lambda: wall, refuse, 1.2), ROOT)[0][1]["sensors"]["N"] == "wall"


def test_a_stale_order_publishes_nothing_and_changes_nothing() -> None:
    core = ready()
    core.on_message(ROOT + "units/u1/order", order_bytes("o1", 2, [Cell(1, 1)]), 0.3)
    for update in (2, 1):
        stale = order_bytes("o1", update, [Cell(0, 0)])
        assert core.on_message(ROOT + "units/u1/order", stale, 0.3) == []
    assert core.logic.released == [Cell(1, 1)]


def sent_before(seconds: float, oid: str, update: int, released: list[Cell]) -> bytes:
    """An order whose header says it left the coordinator `seconds` before FIXED."""
    stamped = Header(seq=0, timestamp=FIXED - timedelta(seconds=seconds), sender="coordinator")
    return encode(Order(header=stamped, order_id=oid, update_id=update, released=released))


def test_an_order_later_than_the_hold_time_is_not_driven_the_unit_holds_and_says_so_once() -> None:
    # A thin link piles orders up (and the stop behind them): driving them would drive the past.
    core = ready()  # its own clock says FIXED, as the punctual orders do
    on_time = order_bytes("o1", 1, [Cell(1, 1)])
    assert published(core.on_message(ROOT + "units/u1/order", on_time, 0.3), ROOT) == [
        direction("E")
    ]
    # Later than its hold time, but by a busy host's second: still driven (rule 7's 1.5 s).
    assert core.logic.hold_timeout_s < 1.0
    busy = sent_before(1.0, "o1", 2, [Cell(1, 1)])
    assert published(core.on_message(ROOT + "units/u1/order", busy, 0.32), ROOT) == []
    assert core.logic.late_by_s is None and core.logic.released == [Cell(1, 1)]
    late = sent_before(2.0, "o1", 2, [Cell(1, 1), Cell(2, 1)])
    reason = "orders come 2.0 s late: holding until on time"
    held = {
        "status": "holding",
        "wait_reason": "orders come 2.0 s late; holding",
        "order_id": "o1",
        "order_update_id": 2,
        "errors": [{"code": "late_order", "message": reason}],
    }
    assert published(core.on_message(ROOT + "units/u1/order", late, 0.35), ROOT) == [
        error(0, "units/u1/order", reason),
        state(2, **held),
        direction("-"),  # the LEDs no longer show a move
    ]
    later = sent_before(2.5, "o1", 3, [Cell(1, 1)])
    assert core.on_message(ROOT + "units/u1/order", later, 0.4) == []  # told once
    core.tick(lambda: FREE, refuse, 0.45)  # no move: the released square was dropped
    assert (core.logic.position, core.logic.released) == (Cell(0, 1), [])
    # On time again: driven again.
    assert core.on_message(ROOT + "units/u1/order", order_bytes("o1", 4, [Cell(1, 1)]), 0.5)
    core.tick(lambda: FREE, allow, 0.55)
    assert (core.logic.position, core.logic.status) == (Cell(1, 1), "moving")
    # Late again within 10 s: held, not told (a flapping link must not flood `errors`) ...
    again = sent_before(3.0, "o1", 5, [Cell(2, 1)])
    assert core.on_message(ROOT + "units/u1/order", again, 0.6) == []
    assert core.logic.late_by_s == pytest.approx(3.0, abs=0.01) and core.logic.released == []
    core.on_message(ROOT + "units/u1/order", order_bytes("o1", 6, [Cell(2, 1)]), 0.7)
    # ... told again once 10 s have passed since it last told.
    told = core.on_message(ROOT + "units/u1/order", sent_before(3.0, "o1", 7, []), 10.4)
    assert [p[0] for p in published(told, ROOT)][:1] == ["errors"]


def test_clocks_that_disagree_are_no_lateness_and_a_restarted_coordinator_is_learnt_afresh() -> (
    None
):
    core = ready()
    for update in (1, 2):  # the coordinator's clock an hour behind the unit's, steadily
        behind = sent_before(3600.0, "o1", update, [Cell(1, 1)])
        core.on_message(ROOT + "units/u1/order", behind, 0.3)
        assert core.logic.late_by_s is None and core.logic.released == [Cell(1, 1)]
    # A coordinator started afresh (its status from seq 0), on a host whose clock is right.
    restarted = CoordinatorStatus(header=header("coordinator"), state="online", step_period_s=0.1)
    told = core.on_message(ROOT + "coordinator/status", encode(restarted), 0.35)
    # A new session is told again who the unit is (tests/robots/test_robots_sessions.py).
    assert [t for t, *_ in published(told, ROOT)] == [
        "units/u1/connection",
        "units/u1/factsheet",
        "units/u1/state",
    ]
    core.on_message(ROOT + "units/u1/order", order_bytes("c2", 1, [Cell(1, 1)]), 0.4)
    assert core.logic.late_by_s is None and core.logic.order_id == "c2"
    # Without a restart, that same hour would have been lateness.
    core = ready()
    core.on_message(ROOT + "units/u1/order", order_bytes("o1", 1, [Cell(1, 1)]), 0.3)
    core.on_message(ROOT + "units/u1/order", sent_before(3600.0, "o1", 2, [Cell(1, 1)]), 0.35)
    assert core.logic.late_by_s == pytest.approx(3600.0, abs=0.01)


def test_a_refused_order_is_reported_with_its_reason_and_in_the_state() -> None:
    core = ready()
    outs = core.on_message(ROOT + "units/u1/order", order_bytes("o2", 1, [Cell(3, 1)]), 0.3)
    reason = (
        "order 'o2' update 1: released square [3, 1] is not adjacent to the unit's square [0, 1]"
    )
    assert published(outs, ROOT) == [
        error(0, "units/u1/order", reason),
        state(2, errors=[{"code": "bad_order", "message": reason}]),
    ]
    assert core.logic.order_id is None


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (
            b"{not json",
            "Order: malformed JSON (Invalid JSON: key must be a string at line 1 column 2)",
        ),
        (b'{"order_id": "x"}', "Order: field 'header': Field required (and 2 more problems)"),
        (
            b'{"header": ' + b" " * 20000 + b"}",
            "Order: payload of 20012 bytes exceeds the limit of 16384",
        ),
    ],
    ids=["malformed", "incomplete", "oversized"],
)
def test_an_unreadable_order_is_reported_and_changes_nothing(payload: bytes, reason: str) -> None:
    core = ready()
    assert published(core.on_message(ROOT + "units/u1/order", payload, 0.3), ROOT) == [
        error(0, "units/u1/order", reason),
        state(2, errors=[{"code": "bad_order", "message": reason}]),
    ]


def test_orders_for_another_unit_and_unknown_topics_publish_nothing() -> None:
    core = ready()
    assert core.on_message(ROOT + "units/u2/order", order_bytes("o1", 1, [Cell(1, 1)]), 0.3) == []
    assert core.on_message("elsewhere/v1/units/u1/order", b"{}", 0.3) == []
    assert core.logic.order_id is None


# ---- the emergency stop -----------------------------------------------------------------------


def test_the_stop_engaged_halts_drops_the_release_and_lights_every_led() -> None:
    core = ready()
    core.on_message(ROOT + "units/u1/order", order_bytes("o1", 1, [Cell(1, 1)]), 0.3)
    outs = core.on_message(ROOT + "fleet/estop", b"engaged|dashboard|operator pressed STOP", 0.3)
    assert published(outs, ROOT) == [
        state(
            2,
            status="stopped",
            wait_reason="emergency stop engaged",
            leds=LEDS_ALL,
            order_id="o1",
            order_update_id=1,
            estop=True,
        ),
        direction("-"),
    ]


def test_the_stop_released_lets_the_unit_wait_for_its_next_order() -> None:
    core = ready()
    core.on_message(ROOT + "fleet/estop", b"engaged|dashboard|", 0.3)
    outs = core.on_message(ROOT + "fleet/estop", b"released|dashboard|area checked", 0.4)
    assert published(outs, ROOT) == [state(3)]


@pytest.mark.parametrize("payload", [b"releasd|tester|typo", b""], ids=["typo", "cleared"])
def test_an_unreadable_stop_is_reported_and_never_releases(payload: bytes) -> None:
    core = ready()
    core.on_message(ROOT + "fleet/estop", b"engaged|dashboard|", 0.3)
    reason = (
        f"estop: {payload.decode()!r} is not 'engaged|<by>|<reason>' or 'released|<by>|<reason>'"
    )
    stopped = {"status": "stopped", "wait_reason": "emergency stop engaged", "leds": LEDS_ALL}
    assert published(core.on_message(ROOT + "fleet/estop", payload, 0.4), ROOT) == [
        error(0, "fleet/estop", reason),
        state(3, estop=True, errors=[{"code": "bad_estop", "message": reason}], **stopped),
    ]
    assert core.logic.estop


STOPPED = {"status": "stopped", "wait_reason": "emergency stop engaged", "leds": LEDS_ALL}


def test_a_device_press_stops_the_unit_until_released_and_cleared() -> None:
    core = ready()
    press = ROOT + "devices/dev1/stop"
    outs = core.on_message(press, b"engaged|dev1|button", 0.3)
    assert published(outs, ROOT) == [state(2, estop=True, **STOPPED)]
    # The operator's release alone does not free it: the press is still held on the broker...
    core.on_message(ROOT + "fleet/estop", b"released|dashboard|checked", 0.4)
    assert core.logic.estop
    # ...until the coordinator clears it (after the release).
    assert published(core.on_message(press, b"", 0.5), ROOT) == [state(4)]
    assert not core.logic.estop


@pytest.mark.parametrize(
    ("topic", "payload", "reason"),
    [
        ("devices/dev1/stop", b"released|dev1|button", "a press can only engage"),
        ("units/u2/stop", b"engaged|dashboard|x", "names 'dashboard' as its source"),
        ("devices/dev1/stop", b"engaged|dev1|two\nlines", "one line"),
    ],
)
def test_a_press_that_is_no_press_is_reported_and_changes_nothing(
    topic: str, payload: bytes, reason: str
) -> None:
    core = ready()
    core.on_message(ROOT + "units/u2/stop", b"engaged|u2|bumper", 0.3)
    outs = published(core.on_message(ROOT + topic, payload, 0.4), ROOT)
    assert outs[0][0] == "errors" and reason in str(outs[0][1])
    assert core.logic.estop  # still held by u2's press


# ---- the coordinator's status, goals, other units ---------------------------------------------


def test_the_coordinators_status_sizes_the_hold_timeout_and_a_bad_one_is_refused() -> None:
    core = ready()
    status = CoordinatorStatus(header=COORDINATOR("coordinator"), state="online", step_period_s=1.0)
    # Replayed on subscribing: the coordinator was there before the unit announced itself.
    assert core.on_message(ROOT + "coordinator/status", encode(status), 0.3, retained=True) == []
    assert core.logic.hold_timeout_s == 3.0
    ((topic, report, _, _),) = published(
        core.on_message(ROOT + "coordinator/status", b"{broken", 0.3), ROOT
    )
    assert topic == "errors" and report["reason"].startswith("CoordinatorStatus: malformed JSON")
    assert core.logic.hold_timeout_s == 3.0
    assert core.on_message(ROOT + "coordinator/status", b"", 0.3) == []  # cleared: nothing to read


def test_an_accepted_goal_shows_the_first_move_of_the_route() -> None:
    core = ready("standalone")
    goal = encode(Goal(header=COORDINATOR("goal"), target=Cell(4, 1)))
    assert published(core.on_message(ROOT + "units/u1/goal", goal, 0.3), ROOT) == [
        state(
            2,
            mode="standalone",
            goal=[4, 1],
            direction="E",
            status="waiting",
            wait_reason="moves at the next step",
            leds=LED_E,
        ),
        direction("E"),
    ]


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (
            encode(Goal(header=COORDINATOR("goal"), target=Cell(1, 1))),
            "goal [1, 1] is off the map, on a wall or an obstacle",
        ),
        (b'{"target": [1, 1]}', "Goal: field 'header': Field required"),
    ],
    ids=["on-a-wall", "no-header"],
)
def test_a_refused_goal_is_reported_and_changes_nothing(payload: bytes, reason: str) -> None:
    core = ready("standalone", rows=(".....", ".@...", "....."))
    code = "bad_goal"
    assert published(core.on_message(ROOT + "units/u1/goal", payload, 0.3), ROOT) == [
        error(0, "units/u1/goal", reason),
        state(2, mode="standalone", errors=[{"code": code, "message": reason}]),
    ]
    assert core.logic.goal is None


def test_a_goal_for_a_coordinated_unit_is_ignored() -> None:
    core = ready()
    goal = encode(Goal(header=COORDINATOR("goal"), target=Cell(4, 1)))
    assert core.on_message(ROOT + "units/u1/goal", goal, 0.3) == []
    assert core.logic.goal is None


def test_another_units_state_tells_where_it_stands_and_publishes_nothing() -> None:
    core = ready()
    theirs = encode(ready().logic.report(COORDINATOR("state")))
    assert core.peer_position(ROOT + "units/u2/state", theirs) == ("u2", Cell(0, 1))
    assert core.peer_position(ROOT + "units/u1/state", theirs) is None
    assert core.peer_position(ROOT + "units/u2/state", b"{") is None
    assert core.on_message(ROOT + "units/u2/state", theirs, 0.3) == []


# ---- energy -----------------------------------------------------------------------------------

# Per step of 0.1 s: standing costs 0.2 %, charging adds 0.1 %; u1 starts on the charger (0, 1).
ENERGY = EnergyModel(move_pct=1.0, idle_pct_per_s=2.0, charge_pct_per_s=1.0)
CHARGER = Cell(0, 1)


def powered(start_pct: float) -> UnitCore:
    """u1 as `ready` makes it, with a battery at `start_pct` (before its first step's drain)."""
    logic = UnitLogic(
        "u1",
        GridMap.from_rows(OPEN),
        Cell(0, 1),
        5.0,
        0.1,
        battery=Battery(ENERGY, start_pct),
        chargers=frozenset({CHARGER}),
    )
    core = UnitCore(logic, Topics("gf"), color="#d32f2f", stamp=stamper("u1"))
    core.start(0.0)
    core.will()
    core.on_connect(0.0)
    core.tick(lambda: FREE, refuse, 0.2)
    return core


def charge_order(update: int, charge: Cell | None) -> bytes:
    return encode(
        Order(
            header=COORDINATOR("order"), order_id="o1", update_id=update, released=[], charge=charge
        )
    )


def test_the_factsheet_says_the_energy_model_and_every_state_the_exact_charge() -> None:
    logic = UnitLogic(
        "u1", GridMap.from_rows(OPEN), Cell(0, 1), 5.0, 0.1, battery=Battery(ENERGY, 83.46)
    )
    core = UnitCore(logic, Topics("gf"), color="#d32f2f", stamp=stamper("u1"))
    core.start(0.0)
    factsheet, told = published(core.on_connect(0.0), ROOT)[1:3]
    assert factsheet[1]["energy"] == {
        "move_pct": 1.0,
        "idle_pct_per_s": 2.0,
        "charge_pct_per_s": 1.0,
    }
    assert (told[1]["battery_pct"], told[1]["charging"]) == (83.5, False)


def test_a_draining_unit_sends_its_state_when_the_whole_percent_changes_or_for_the_heartbeat() -> (
    None
):
    core = powered(50.5)  # 50.3 after its first step, whose state went out
    # Its steps drain it, not the clock: every step at the same `now`, 0.2 % a step all the same.
    sent = [published(core.tick(lambda: FREE, refuse, 0.2), ROOT) for _ in range(6)]
    # 50.1, 49.9 (a new whole percent), 49.7, 49.5, 49.3 (the heartbeat), 49.1
    assert [bool(s) for s in sent] == [False, True, False, False, True, False]
    assert sent[1] == [state(2, step=3, battery_pct=49.9)]
    assert sent[4] == [state(3, step=6, battery_pct=49.3)]  # the exact figure, every time


def test_charging_goes_out_with_the_next_step_and_its_end_too() -> None:
    core = powered(50.3)  # 50.1 after its first step
    assert core.on_message(ROOT + "units/u1/order", charge_order(1, CHARGER), 0.25) == []
    assert published(core.tick(lambda: FREE, refuse, 0.3), ROOT) == [
        state(2, step=2, order_id="o1", order_update_id=1, battery_pct=50.2, charging=True)
    ]
    assert core.tick(lambda: FREE, refuse, 0.4) == []  # 50.3: nothing new
    assert core.on_message(ROOT + "units/u1/order", charge_order(2, None), 0.45) == []
    assert published(core.tick(lambda: FREE, refuse, 0.5), ROOT) == [
        state(3, step=4, order_id="o1", order_update_id=2, battery_pct=50.1)
    ]


def test_ordered_to_charge_where_no_charger_is_the_next_state_says_so_once() -> None:
    core = powered(50.3)
    elsewhere = encode(
        Order(
            header=COORDINATOR("order"),
            order_id="o1",
            update_id=1,
            released=[Cell(1, 1)],
            charge=Cell(1, 1),
        )
    )
    assert published(core.on_message(ROOT + "units/u1/order", elsewhere, 0.25), ROOT) == [
        direction("E")
    ]
    no_charger = {
        "code": "no_charger",
        "message": "ordered to charge on [1, 1], which is no charger",
    }
    assert published(core.tick(lambda: FREE, allow, 0.3), ROOT) == [
        state(
            2,
            step=2,
            position=[1, 1],
            direction="-",
            status="moving",
            order_id="o1",
            order_update_id=1,
            battery_pct=49.1,
            errors=[no_charger],
        ),
        direction("-"),
    ]
    assert core.tick(lambda: FREE, refuse, 0.4) != []  # no longer moving: news, but no error
    assert core.logic.errors == [] and not core.logic.charging


def test_an_empty_unit_says_why_it_stays() -> None:
    core = powered(0.1)  # 0.0 after its first step
    assert (
        published(
            core.on_message(ROOT + "units/u1/order", order_bytes("o1", 1, [Cell(1, 1)]), 0.25), ROOT
        )
        == []
    )
    assert published(core.tick(lambda: FREE, refuse, 0.3), ROOT) == [
        state(
            2,
            step=2,
            status="waiting",
            wait_reason="battery empty: cannot move",
            order_id="o1",
            order_update_id=1,
            released=[[1, 1]],
            battery_pct=0.0,
        )
    ]
