"""Exactly what the coordinator core publishes for each message it reads and for a step.

No broker: each test injects a message into the pure core (every header stamped at one fixed
time) and compares the whole list of (topic, payload as parsed JSON, QoS, retain) it returns.
"""

from __future__ import annotations

import json
import logging
from datetime import timedelta
from typing import Any

import pytest

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.effects import Effects
from gridfleet.coordinator.views import views_period_s
from gridfleet.errors import ProtocolError
from gridfleet.failures import failure_reason
from gridfleet.grid import Cell, GridMap
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    CancelJob,
    ClearObstacles,
    Connection,
    ControlUnit,
    Factsheet,
    JobHistoryQuery,
    Leds,
    Sensors,
    SetGoal,
    SubmitJob,
    UnitState,
    decode,
    decode_estop,
    encode,
)
from gridfleet.protocol.messages import FINAL_JOB_STATES, Message

from support.coordinator_drive import TOPICS, from_unit, make_core, meet, orders_in, request
from support.effects import FIXED, header, header_json, published

# Four by three squares, a wall at [1, 1].
GRID = GridMap.from_rows(["....", ".@..", "...."])
JOB = {"pickup": [3, 0], "dropoff": [3, 2], "mass_kg": 1.0, "priority": 0}
STATUS = "gridfleet/v1/coordinator/status"
ERRORS = "gridfleet/v1/errors"
JOBS = "gridfleet/v1/fleet/jobs"
MAP = "gridfleet/v1/fleet/map"
ZONES = "gridfleet/v1/fleet/zones"
ROUTES = "gridfleet/v1/fleet/routes"
ORDER = "gridfleet/v1/units/unit1/order"
REPLY = "gridfleet/v1/replies/op"
HOME = Cell(0, 0)  # where unit1 stands


def hdr(seq: int) -> dict[str, Any]:
    """The coordinator's header with `seq` (counted per topic kind)."""
    return header_json("coordinator", seq)


def status(
    seq: int, state: str, *, step: int = 0, estop: bool = False, achieved: float | None = None
) -> dict[str, Any]:
    return {
        "header": hdr(seq),
        "state": state,
        "step": step,
        "step_period_s": 1.0,
        "estop": estop,
        "version": "0.1.0",
        "achieved_step_s": achieved,
    }


def error(seq: int, topic: str, reason: str, request_id: str | None = None) -> Any:
    payload = {"header": hdr(seq), "topic": topic, "reason": reason, "request_id": request_id}
    return (ERRORS, payload, 1, False)


def reply(
    seq: int,
    request_id: str,
    accepted: bool,
    reason: str | None,
    job_id: str | None,
    code: str | None = None,
) -> Any:
    payload = {
        "header": hdr(seq),
        "request_id": request_id,
        "accepted": accepted,
        "reason": reason,
        "job_id": job_id,
        "code": code,
    }
    return (REPLY, payload, 1, False)


def job(state: str, *, unit: str | None = None, **over: Any) -> dict[str, Any]:
    """job-1 (JOB, submitted by op at step 0) as the queue view lists it."""
    out = {"id": "job-1", **JOB, "state": state, "unit": unit, "reason": None}
    out.update(submitted_by="op", created_step=0, done_step=None, wait=None, wait_reason=None)
    out.update(over)
    return out


def jobs_view(seq: int, *jobs: dict[str, Any], done_per_minute: list[int] | None = None) -> Any:
    """The queue view listing `jobs`: those not final under `jobs`, the final ones under `finished`."""
    counts: dict[str, int] = {}
    for j in jobs:
        counts[j["state"]] = counts.get(j["state"], 0) + 1
    shown = [{k: v for k, v in j.items() if v is not None} for j in jobs]  # nulls left out
    body = {
        "header": hdr(seq),
        "jobs": [j for j in shown if j["state"] not in FINAL_JOB_STATES],
        "finished": [j for j in shown if j["state"] in FINAL_JOB_STATES],
        "counts": counts,
        "done_per_minute": done_per_minute or [0] * 10,
    }
    return (JOBS, body, 1, True)


def hold(seq: int, update_id: int, step: int = 1) -> dict[str, Any]:
    """An order to unit1 (its first route) that releases nothing."""
    return {
        "header": hdr(seq),
        "order_id": "n-unit1-1",
        "update_id": update_id,
        "step": step,
        "released": [],
        "planned": [],
        "target": None,
        "action": None,
        "charge": None,
    }


def routes(seq: int, step: int, released: Any = (), planned: Any = (), target: Any = None) -> Any:
    """The routes view with unit1's route."""
    route = {
        "released": list(released),
        "planned": list(planned),
        "target": target,
        "control": None,
        "note": None,  # nothing to say: no closed zone moves or holds it
    }
    return {"header": hdr(seq), "step": step, "routes": {"unit1": route}}


def published_one(out: Outbound) -> Any:
    """One message as `published` shows it."""
    (only,) = published(Effects(publish=(out,)))
    return only


def state(position: Cell = HOME, seq: int = 0, **over: Any) -> UnitState:
    """unit1's state: idle on `position`, sensors all free but the map's edges."""
    msg = UnitState(
        header=header("unit1", seq),
        step=seq,
        position=position,
        direction="-",
        status="idle",
        leds=Leds(),
        sensors=Sensors(N="wall", E="free", S="free", W="wall"),
    )
    return msg.model_copy(update=over)


def submit(request_id: str = "r1", **over: Any) -> SubmitJob:
    fields: dict[str, Any] = {**JOB, "request_id": request_id, "reply_to": "op", **over}
    return SubmitJob(header=header("op"), **fields)


@pytest.fixture
def core() -> CoordinatorCore:
    """Connected (its views out), with unit1 online at [0, 0], 5 kg, a step of 1 s."""
    c = make_core(GRID)
    c.on_connect()
    meet(c, state(), capacity_kg=5.0)
    return c


def under_way(core: CoordinatorCore) -> None:
    """job-1 queued and one step made: unit1 has its first move, to [1, 0]."""
    request(core, "submit_job", submit(), 0.0)
    core.step(1.0)


# ---- the session ------------------------------------------------------------------------------


def test_status_online_offline_and_the_last_will() -> None:
    c = make_core(GRID)
    got = [published_one(c.status(s)) for s in ("broken", "online", "offline")]
    assert got == [
        (STATUS, status(0, "broken"), 1, True),
        (STATUS, status(1, "online"), 1, True),
        (STATUS, status(2, "offline"), 1, True),
    ]


def test_connecting_publishes_the_map_the_queue_and_the_zones_views() -> None:
    c = make_core(GRID)
    assert published(c.on_connect()) == [
        (
            MAP,
            {
                "header": hdr(0),
                "name": "map",
                "width": 4,
                "height": 3,
                "rows": ["....", ".@..", "...."],
                "obstacles": [],
                "chargers": [],
                "places": [],
            },
            1,
            True,
        ),
        jobs_view(0),
        (ZONES, {"header": hdr(0), "zones": []}, 1, True),  # none closed, said at start
    ]
    assert published(c.on_connect())[1] == jobs_view(1)  # every session gets them again


def test_a_clean_stop_holds_every_unit_that_had_an_order(core: CoordinatorCore) -> None:
    assert published(core.halt_orders()) == []  # no order yet: nothing to hold
    under_way(core)
    effects = core.halt_orders()
    assert published(effects) == [(ORDER, hold(1, update_id=2), 1, False)]
    assert effects.awaiting == frozenset()


# ---- unit topics -------------------------------------------------------------------------------


def test_a_unit_saying_it_is_online_publishes_nothing() -> None:
    c = make_core(GRID)
    c.on_connect()
    msg = Connection(header=header("unit2"), state="online")
    effects = from_unit(c, "connection", "unit2", msg, 0.0)
    assert published(effects) == [] and effects.persist == ()
    assert c.world.units["unit2"].connection == "online"


@pytest.mark.parametrize("state_now", ["offline", "broken"])
def test_a_unit_saying_it_left_publishes_nothing_and_gets_no_more_orders(
    core: CoordinatorCore, state_now: str
) -> None:
    msg = Connection(header=header("unit1", seq=1), state=state_now)  # type: ignore[arg-type]
    effects = from_unit(core, "connection", "unit1", msg, 0.5)
    assert published(effects) == [] and effects.persist == ()
    assert core.world.units["unit1"].connection == state_now
    assert published(core.step(1.0)) == [(ROUTES, routes(0, step=1), 0, True)]


@pytest.mark.parametrize(
    ("kind", "model", "payload"),
    [
        ("connection", Connection, b"{"),
        ("connection", Connection, b'{"header": {}, "state": "asleep"}'),
        ("factsheet", Factsheet, b"{"),
        ("factsheet", Factsheet, b"x" * 20000),
    ],
    ids=["connection JSON", "connection fields", "factsheet JSON", "factsheet oversized"],
)
def test_a_bad_connection_or_factsheet_is_reported_and_changes_nothing(
    core: CoordinatorCore, kind: str, model: type[Message], payload: bytes
) -> None:
    before = (core.world.units["unit1"].connection, core.world.capacities())
    effects = from_unit(core, kind, "unit1", payload, 0.5)
    topic = TOPICS.unit(kind, "unit1")
    assert published(effects) == [error(0, topic, codec_reason(model, payload))]
    assert (core.world.units["unit1"].connection, core.world.capacities()) == before


def test_a_factsheet_publishes_nothing() -> None:
    c = make_core(GRID)
    c.on_connect()
    msg = Factsheet(header=header("unit2"), capacity_kg=3.0, step_period_s=0.5)
    assert published(from_unit(c, "factsheet", "unit2", msg, 0.0)) == []
    assert c.world.capacities() == [3.0]


def test_a_state_publishes_nothing(core: CoordinatorCore) -> None:
    assert published(from_unit(core, "state", "unit1", state(Cell(2, 0), seq=2), 0.5)) == []
    assert core.world.units["unit1"].position == (2, 0)


def drive(core: CoordinatorCore, *states: UnitState, now: float = 1.5) -> list[Any]:
    """unit1's states arrive one after the other; what each publishes."""
    return [published(from_unit(core, "state", "unit1", st, now)) for st in states]


def test_a_state_at_the_dropoff_never_finishes_a_job_not_seen_loaded(
    core: CoordinatorCore,
) -> None:
    under_way(core)  # job-1 to_pickup: unit1 on [0, 0], the item on [3, 0]
    # Five squares in nine steps and 5 s is a possible drive; the job was never reported loaded.
    assert drive(core, state(Cell(3, 2), seq=9), now=5.0) == [[]]
    core.step(2.0)
    job = core.jobs.jobs["job-1"]
    assert (job.state, job.unit) == ("to_pickup", "unit1")
    # Nor does a claim to carry it made away from the pickup.
    assert drive(core, state(Cell(3, 1), seq=10, job_id="job-1", load_kg=1.0)) == [[]]
    core.step(3.0)
    assert job.state == "to_pickup"


def test_a_state_jumping_to_the_dropoff_is_refused_and_finishes_nothing(
    core: CoordinatorCore,
) -> None:
    under_way(core)
    loaded = state(Cell(3, 0), seq=3, job_id="job-1", load_kg=1.0)
    assert drive(core, state(Cell(1, 0), seq=1), state(Cell(2, 0), seq=2), loaded) == [[], [], []]
    core.step(2.0)
    assert core.jobs.jobs["job-1"].state == "loaded"
    jump = state(Cell(3, 2), seq=4)  # two squares in one step, the item gone
    assert drive(core, jump) == [
        [
            error(
                0,
                "gridfleet/v1/units/unit1/state",
                "position [3, 2] at step 4 is 2 squares from [3, 0] at step 3, "
                "the last state accepted 0.00 s before",
            )
        ]
    ]
    assert core.world.units["unit1"].position == Cell(3, 0)  # changed nothing
    core.step(3.0)
    assert core.jobs.jobs["job-1"].state == "loaded"
    # Driven there square by square, the drop finishes it.
    assert drive(core, state(Cell(3, 1), seq=4, job_id="job-1", load_kg=1.0), now=3.2) == [[]]
    assert drive(core, state(Cell(3, 2), seq=5), now=3.4) == [[]]
    core.step(4.0)
    assert core.jobs.jobs["job-1"].state == "done"


def test_a_unit_that_reconnects_comes_back_where_it_left(core: CoordinatorCore) -> None:
    # As found: `offline` then `online` let a unit reappear anywhere. A restarted unit says it
    # is online first; it may be a move further on, not across the map.
    online = Connection(header=header("unit1"), state="online")
    from_unit(core, "connection", "unit1", online, 1)
    assert drive(core, state(Cell(3, 2), seq=0)) == [
        [
            error(
                0,
                "gridfleet/v1/units/unit1/state",
                "position [3, 2] is 5 squares from [0, 0], where unit unit1 was last seen: a "
                "unit rejoins where it left (an operator takes it out of service to move it by "
                "hand)",
            )
        ]
    ]
    assert core.world.units["unit1"].position == Cell(0, 0)
    assert drive(core, state(Cell(1, 0), seq=0)) == [[]]  # one square on: a move under way


def test_a_unit_out_of_service_may_be_moved_anywhere_by_hand(core: CoordinatorCore) -> None:
    take_out = ControlUnit(
        header=header("op"), request_id="c1", reply_to="op", unit="unit1", command="out_of_service"
    )
    request(core, "control_unit", take_out, 1.0)
    from_unit(core, "connection", "unit1", Connection(header=header("unit1"), state="online"), 1)
    assert drive(core, state(Cell(3, 2), seq=0)) == [[]]
    assert core.world.units["unit1"].position == Cell(3, 2)


def test_a_state_on_another_units_square_is_refused(core: CoordinatorCore) -> None:
    other = state(Cell(2, 2), seq=0).model_copy(update={"header": header("unit2")})
    from_unit(core, "state", "unit2", other, 1.0)
    assert drive(core, state(Cell(1, 0), seq=1), state(Cell(2, 0), seq=2), now=3.0) == [[], []]
    assert drive(core, state(Cell(2, 1), seq=3), state(Cell(2, 2), seq=4), now=5.0) == [
        [],
        [
            error(
                0,
                "gridfleet/v1/units/unit1/state",
                "position [2, 2] is held by unit unit2 (its latest state is there): two units "
                "never share a square",
            )
        ],
    ]
    assert core.world.units["unit1"].position == Cell(2, 1)


def test_a_step_counter_run_ahead_does_not_buy_a_jump(core: CoordinatorCore) -> None:
    # As found: step + 100 jumped anywhere; the time since the last state bounds the move too.
    assert drive(core, state(Cell(1, 0), seq=1), now=1.0) == [[]]
    far = drive(core, state(Cell(3, 2), seq=101), now=1.2)
    assert far[0][0][1]["reason"] == (
        "position [3, 2] at step 101 is 4 squares from [1, 0] at step 1, the last state "
        "accepted 0.20 s before: faster than unit unit1 can drive (at most 3.2 squares by now: a "
        "square every 1.00 s, the fleet's step period, with a slack of 3 squares)"
    )
    assert core.world.units["unit1"].position == Cell(1, 0)


def test_an_obstacle_far_from_the_unit_is_refused_and_one_seen_free_is_cleared(
    core: CoordinatorCore,
) -> None:
    # As found: a unit reported a fake row of obstacles across the map, and nothing cleared it.
    far = state(Cell(0, 0), seq=1, obstacles=[Cell(3, 2)])
    assert drive(core, far)[0][0][1]["reason"] == (
        "obstacle [3, 2] is not next to the unit (at [0, 0]): a unit reports only what its own "
        "sensors see"
    )
    assert core.world.obstacles == set()
    seen = Sensors(N="wall", E="free", S="obstacle", W="wall")
    assert drive(core, state(Cell(0, 0), seq=2, obstacles=[Cell(0, 1)], sensors=seen)) == [[]]
    assert core.world.obstacles == {Cell(0, 1)}
    free = Sensors(N="wall", E="free", S="free", W="wall")
    assert drive(core, state(Cell(0, 0), seq=3, sensors=free)) == [[]]
    assert core.world.obstacles == set() and core.world.grid.is_free(Cell(0, 1))


def test_a_new_obstacle_goes_into_the_map_at_the_next_step(core: CoordinatorCore) -> None:
    news = state(
        Cell(0, 0),
        seq=1,
        obstacles=[(0, 1)],
        sensors=Sensors(N="wall", E="free", S="obstacle", W="wall"),
    )
    assert published(from_unit(core, "state", "unit1", news, 0.5)) == []
    assert published(core.step(1.0)) == [
        (ORDER, hold(0, update_id=1), 1, False),
        (ROUTES, routes(0, step=1), 0, True),
        (
            MAP,
            {
                "header": hdr(1),
                "name": "map",
                "width": 4,
                "height": 3,
                "rows": ["....", ".@..", "...."],
                "obstacles": [[0, 1]],
                "chargers": [],
                "places": [],
            },
            1,
            True,
        ),
    ]


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (
            b"{",
            "UnitState: malformed JSON (Invalid JSON: EOF while parsing an object at line 1 column 1)",
        ),
        (
            encode(state()).replace(b'"1.6"', b'"9.9"'),
            "UnitState: field 'header.version': Value error, protocol version '9.9' is not '1.6'",
        ),
        (encode(state(Cell(1, 1))), "position [1, 1] is on a wall"),
        (
            b"x" * 20000,
            "UnitState: payload of 20000 bytes exceeds the limit of 16384",
        ),
    ],
    ids=["malformed JSON", "wrong version", "on a wall", "oversized"],
)
def test_a_bad_state_is_reported_and_changes_nothing(
    core: CoordinatorCore, payload: bytes, reason: str
) -> None:
    effects = from_unit(core, "state", "unit1", payload, 0.5)
    assert published(effects) == [error(0, "gridfleet/v1/units/unit1/state", reason)]
    assert effects.log == (
        (logging.INFO, f"refused a message on {TOPICS.unit('state', 'unit1')}: {reason}"),
    )
    assert core.world.units["unit1"].position == (0, 0)
    assert core.errors_reported == 1


# ---- the step ----------------------------------------------------------------------------------


def test_a_step_orders_the_move_shows_the_route_and_the_changed_queue(
    core: CoordinatorCore,
) -> None:
    request(core, "submit_job", submit(), 0.0)
    effects = core.step(1.0)
    assert published(effects) == [
        (
            ORDER,
            {
                "header": hdr(0),
                "order_id": "n-unit1-1",
                "update_id": 1,
                "step": 1,
                "released": [[1, 0]],
                "planned": [[2, 0], [3, 0]],
                "target": [3, 0],
                "action": {"kind": "pick", "job_id": "job-1", "square": [3, 0], "mass_kg": 1.0},
                "charge": None,
            },
            1,
            False,
        ),
        (ROUTES, routes(0, 1, [[1, 0]], [[2, 0], [3, 0]], [3, 0]), 0, True),
        jobs_view(2, job("to_pickup", unit="unit1")),
    ]
    assert [j.id for j in effects.persist] == ["job-1"]
    # The next step waits (at most a step period) for unit1 to acknowledge its order.
    assert (effects.awaiting, effects.acks_until) == (frozenset({"unit1"}), 2.0)


def test_a_state_acknowledging_the_order_ends_the_wait(core: CoordinatorCore) -> None:
    under_way(core)
    assert from_unit(core, "state", "unit1", state(seq=1), 1.2).awaiting == {"unit1"}
    ack = state(seq=2, order_id="n-unit1-1", order_update_id=1, released=[(1, 0)])
    effects = from_unit(core, "state", "unit1", ack, 1.3)
    assert published(effects) == [] and effects.awaiting == frozenset()


def test_a_jumped_update_id_is_reported_and_replaced_by_a_hold_under_a_new_order(
    core: CoordinatorCore,
) -> None:
    under_way(core)  # n-unit1-1 update 1 went out
    # unit1 took a forged order: our order id, an update id we never sent.
    forged = state(seq=1, order_id="n-unit1-1", order_update_id=2_000_000_000, released=[(1, 0)])
    effects = from_unit(core, "state", "unit1", forged, 1.2)
    reason = (
        "unit unit1 follows update 2000000000 of order n-unit1-1, which was never sent (the latest"
        " is 1): a forged order; it gets a halt order under a new order"
    )
    assert published(effects) == [error(0, "gridfleet/v1/units/unit1/state", reason)]
    assert effects.awaiting == frozenset()
    # The next order is new (the unit takes it at once, whatever update it followed) and holds.
    order = orders_in(core.step(2.0))["unit1"]
    assert (order.order_id, order.update_id, order.released) == ("n-unit1-2", 1, [])


def test_a_step_with_nothing_to_do_holds_and_waits_for_no_unit() -> None:
    c = make_core(GRID)
    c.on_connect()
    effects = c.step(1.0)
    assert published(effects) == [(ROUTES, {"header": hdr(0), "step": 1, "routes": {}}, 0, True)]
    assert (effects.awaiting, effects.acks_until) == (frozenset(), None)


def test_a_lost_unit_gets_no_order_and_an_empty_route(core: CoordinatorCore) -> None:
    assert published(core.step(10.0)) == [(ROUTES, routes(0, step=1), 0, True)]


# ---- the emergency stop ------------------------------------------------------------------------


def estop(core: CoordinatorCore, payload: bytes, now: float = 1.5) -> Any:
    return core.on_message(TOPICS.fleet("estop"), payload, now)


def test_engaging_the_stop_holds_every_unit_at_once_and_says_so(core: CoordinatorCore) -> None:
    under_way(core)
    effects = estop(core, b"engaged|dashboard|operator pressed STOP")
    assert published(effects) == [
        (ORDER, hold(1, update_id=2), 1, False),
        (STATUS, status(0, "online", step=1, estop=True), 1, True),
    ]
    assert effects.log == (
        (logging.WARNING, "emergency stop ENGAGED by dashboard: operator pressed STOP"),
    )
    assert effects.awaiting == frozenset()  # holds need no acknowledgement
    assert published(estop(core, b"engaged|device1|button")) == []  # idempotent


def test_a_step_under_the_stop_releases_nothing(core: CoordinatorCore) -> None:
    under_way(core)
    estop(core, b"engaged|dashboard|x")
    orders = orders_in(core.step(2.0))
    assert orders["unit1"].released == [] and orders["unit1"].action is None


def test_the_stop_withdraws_a_step_s_moves_not_yet_sent(core: CoordinatorCore) -> None:
    request(core, "submit_job", submit(), 0.0)
    step = core.step(1.0)
    order, route = step.publish[0], step.publish[1]
    assert not core.withdrawn(order)
    estop(core, b"engaged|dashboard|x")  # arrives while the step's messages are going out
    assert core.withdrawn(order) and not core.withdrawn(route)
    estop(core, b"released|dashboard|ok")
    assert not core.withdrawn(order)


def test_releasing_the_stop_says_so_and_sends_no_order(core: CoordinatorCore) -> None:
    under_way(core)
    estop(core, b"engaged|dashboard|x")
    effects = estop(core, b"released|dashboard|area checked")
    assert published(effects) == [(STATUS, status(1, "online", step=1, estop=False), 1, True)]
    assert effects.log == ((logging.WARNING, "emergency stop released by dashboard: area checked"),)


ESTOP = "gridfleet/v1/fleet/estop"


def test_a_malformed_stop_is_reported_and_never_releases(core: CoordinatorCore) -> None:
    # It replaced the retained `engaged` on the broker: the last engaged signal goes out again.
    estop(core, b"engaged|dashboard|x")
    assert published(estop(core, b"released")) == [
        error(
            0,
            "gridfleet/v1/fleet/estop",
            "estop: 'released' is not 'engaged|<by>|<reason>' or 'released|<by>|<reason>'",
        ),
        (ESTOP, "engaged|dashboard|x", 1, True),
    ]
    assert core.estop


def test_a_cleared_retained_stop_is_reported_and_never_releases(core: CoordinatorCore) -> None:
    # Anyone can delete a retained message with an empty payload: that is no release.
    estop(core, b"engaged|dashboard|x")
    effects = estop(core, b"")
    assert published(effects) == [
        error(0, "gridfleet/v1/fleet/estop", codec_estop_reason(b"")),
        (ESTOP, "engaged|dashboard|x", 1, True),  # the latch restored on the broker
    ]
    assert core.estop
    assert [o.released for o in orders_in(core.step(2.0)).values()] == [[]]


@pytest.mark.parametrize("payload", [b"", b"released", b"\xff\xfe", b"engaged|bad/id|x"])
def test_the_restored_stop_is_the_last_engaged_signal_read(
    core: CoordinatorCore, payload: bytes
) -> None:
    estop(core, b"engaged|dashboard|operator pressed STOP")
    estop(core, b"engaged|device1|button")  # idempotent, but now the broker's retained value
    effects = estop(core, payload)
    assert published(effects)[1:] == [(ESTOP, "engaged|device1|button", 1, True)]
    # Our own restored signal comes back to us: idempotent, nothing more goes out.
    assert published(estop(core, effects.publish[1].payload)) == []


def test_a_cleared_stop_that_is_not_engaged_is_only_reported(core: CoordinatorCore) -> None:
    assert published(estop(core, b"")) == [error(0, ESTOP, codec_estop_reason(b""))]
    estop(core, b"engaged|dashboard|x")
    estop(core, b"released|dashboard|ok")
    assert published(estop(core, b"")) == [error(1, ESTOP, codec_estop_reason(b""))]
    assert published(estop(core, b"released")) == [error(2, ESTOP, codec_estop_reason(b"released"))]
    assert not core.estop


def test_a_latch_the_broker_lost_is_re_asserted_once_after_reconnecting(
    core: CoordinatorCore,
) -> None:
    estop(core, b"engaged|dashboard|x")
    core.on_connect(10.0)  # a restarted broker: no retained latch will come
    assert ESTOP not in [o.topic for o in core.step(10.5).publish]  # it may still arrive
    effects = core.step(11.0)
    assert published(effects)[0] == (ESTOP, "engaged|dashboard|x", 1, True)
    assert (logging.WARNING, "emergency stop re-asserted on the broker (dashboard)") in effects.log
    assert ESTOP not in [o.topic for o in core.step(12.0).publish]  # once


@pytest.mark.parametrize("retained", [b"released|operator|done while away", b"engaged|dashboard|x"])
def test_a_latch_still_on_the_broker_is_not_re_asserted(
    core: CoordinatorCore, retained: bytes
) -> None:
    estop(core, b"engaged|dashboard|x")
    core.on_connect(10.0)
    estop(core, retained, 10.1)  # the broker kept it (an operator may have released it meanwhile)
    assert ESTOP not in [o.topic for o in core.step(12.0).publish]
    assert core.estop == retained.startswith(b"engaged")


PRESS = "gridfleet/v1/devices/dev1/stop"
UNIT_PRESS = "gridfleet/v1/units/unit2/stop"


def press(core: CoordinatorCore, payload: bytes, topic: str = PRESS) -> Any:
    return core.on_message(topic, payload, 1.5)


def test_a_press_stops_the_fleet_and_is_mirrored_into_the_latch(core: CoordinatorCore) -> None:
    under_way(core)
    effects = press(core, b"engaged|dev1|button")
    assert published(effects) == [
        (ESTOP, "engaged|dev1|button", 1, True),  # only operators can release the latch
        (ORDER, hold(1, update_id=2), 1, False),
        (STATUS, status(0, "online", step=1, estop=True), 1, True),
    ]
    assert effects.log == ((logging.WARNING, "emergency stop ENGAGED by dev1: button"),)
    # The mirror comes back, and a second press while the latch is engaged is not mirrored again.
    assert published(estop(core, b"engaged|dev1|button")) == []
    assert published(press(core, b"engaged|unit2|bumper", UNIT_PRESS)) == []


def test_a_source_clearing_its_own_press_does_not_release_the_fleet(core: CoordinatorCore) -> None:
    press(core, b"engaged|dev1|button")
    estop(core, b"engaged|dev1|button")  # the mirror
    assert published(press(core, b"")) == []
    assert core.estop
    assert [o.released for o in orders_in(core.step(2.0)).values()] == [[]]


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"released|dev1|button", "a press can only engage"),
        (b"engaged|dashboard|x", "names 'dashboard' as its source"),
        (b"engaged", "is not 'engaged|<by>|<reason>'"),
    ],
)
def test_a_press_that_is_no_press_is_reported_and_changes_nothing(
    core: CoordinatorCore, payload: bytes, reason: str
) -> None:
    press(core, b"engaged|dev1|button")
    estop(core, b"engaged|dev1|button")
    effects = published(press(core, payload))
    assert len(effects) == 1 and effects[0][0] == "gridfleet/v1/errors"
    assert reason in effects[0][1]["reason"] and core.estop


def test_an_operator_release_clears_every_held_press(core: CoordinatorCore) -> None:
    press(core, b"engaged|dev1|button")
    press(core, b"engaged|unit2|bumper", UNIT_PRESS)
    estop(core, b"engaged|dev1|button")
    effects = estop(core, b"released|dashboard|area checked")
    assert published(effects) == [
        (PRESS, "", 1, True),  # cleared, so that no restart reads them again
        (UNIT_PRESS, "", 1, True),
        (STATUS, status(1, "online", estop=False), 1, True),
    ]
    assert not core.estop
    assert published(press(core, b"")) == []  # our own clearing comes back: nothing more


def test_a_released_latch_replayed_on_reconnect_does_not_clear_a_press(
    core: CoordinatorCore,
) -> None:
    # A press arrived and the connection broke before its copy into the latch went out: the
    # broker still holds the old `released`, which a reconnect replays. That is no release.
    estop(core, b"released|operator|earlier")
    press(core, b"engaged|dev1|button")
    core.on_connect(10.0)
    effects = estop(core, b"released|operator|earlier", 10.1)
    assert PRESS not in [o.topic for o in effects.publish]  # the press is not cleared
    assert core.estop


def test_a_press_read_on_restart_under_a_released_latch_stops_the_fleet_again() -> None:
    # Pressed while the coordinator was away: the broker's latch still says released.
    fresh = make_core(GRID)
    estop(fresh, b"released|dashboard|earlier")
    effects = press(fresh, b"engaged|dev1|button")
    assert published(effects)[0] == (ESTOP, "engaged|dev1|button", 1, True)
    assert fresh.estop


# ---- requests ----------------------------------------------------------------------------------


def test_an_accepted_job_gets_a_reply_and_the_queue_view_at_once(core: CoordinatorCore) -> None:
    effects = request(core, "submit_job", submit(), 0.0)
    assert published(effects) == [
        reply(0, "r1", True, None, "job-1"),
        jobs_view(1, job("queued")),
    ]
    assert [j.id for j in effects.persist] == ["job-1"]


def test_a_job_off_the_map_is_refused_and_not_listed(core: CoordinatorCore) -> None:
    effects = request(core, "submit_job", submit(pickup=(12, 3)), 0.0)
    reason = "pickup [12, 3] is off the 4x3 map"
    assert published(effects) == [
        error(0, "gridfleet/v1/requests/submit_job", f"SubmitJob: {reason}", "r1"),
        reply(0, "r1", False, reason, None, "bad_square"),
    ]
    assert effects.persist == ()


def test_a_job_too_heavy_for_every_unit_is_refused_and_listed_as_rejected(
    core: CoordinatorCore,
) -> None:
    effects = request(core, "submit_job", submit(mass_kg=50.0), 0.0)
    reason = "mass 50.0 kg exceeds every unit's capacity (largest 5.0 kg)"
    assert published(effects) == [
        error(0, "gridfleet/v1/requests/submit_job", f"SubmitJob: {reason}", "r1"),
        reply(0, "r1", False, reason, "job-1", "too_heavy"),
        jobs_view(1, job("rejected", mass_kg=50.0, reason=reason)),
    ]


def test_a_job_history_query_goes_to_the_shell_and_a_bad_range_is_refused_with_a_page(
    core: CoordinatorCore,
) -> None:
    since = FIXED - timedelta(hours=1)
    good = JobHistoryQuery(header=header("op"), request_id="h1", reply_to="op", since=since)
    effects = request(core, "job_history", good, 0.0)
    # Checked here, answered by the shell from the store (records.py), as the audit is.
    assert (published(effects), [r.query for r in effects.records]) == ([], [good])
    bad = good.model_copy(update={"request_id": "h2", "until": since - timedelta(hours=1)})
    effects = request(core, "job_history", bad, 1.0)
    problem = "since 2026-11-21T09:00:00Z is not before until 2026-11-21T08:00:00Z"
    page = {
        "header": hdr(0),
        "request_id": "h2",
        "accepted": False,
        "reason": problem,
        "entries": [],
        "next_cursor": None,
        "charges": [],
    }
    assert effects.records == ()
    assert published(effects) == [
        error(0, "gridfleet/v1/requests/job_history", f"JobHistoryQuery: {problem}", "h2"),
        ("gridfleet/v1/history/replies/op", page, 1, False),
    ]
    data = json.loads(encode(good.model_copy(update={"request_id": "h3"})))
    unreadable = json.dumps({**data, "since": "last week"}).encode()
    effects = request(core, "job_history", unreadable, 2.0)
    (refused, answer) = published(effects)
    assert refused[0] == ERRORS and refused[1]["request_id"] == "h3"
    assert "since" in refused[1]["reason"]
    assert answer == reply(0, "h3", False, refused[1]["reason"], None, "invalid")
    assert effects.records == () and core.jobs.jobs == {}


def test_a_refusal_without_reply_to_goes_to_errors_only(core: CoordinatorCore) -> None:
    effects = request(core, "submit_job", submit(pickup=(1, 1), reply_to=None), 0.0)
    reason = "SubmitJob: pickup [1, 1] is on a wall"
    assert published(effects) == [error(0, "gridfleet/v1/requests/submit_job", reason, "r1")]


def test_cancelling_a_queued_job_and_an_unknown_one(core: CoordinatorCore) -> None:
    request(core, "submit_job", submit(), 0.0)
    cancel = CancelJob(header=header("op"), request_id="c1", reply_to="op", job_id="job-1")
    effects = request(core, "cancel_job", cancel, 1.0)
    assert published(effects) == [
        reply(1, "c1", True, None, "job-1"),
        jobs_view(2, job("cancelled", reason="cancelled by op", done_step=0)),
    ]
    again = cancel.model_copy(update={"request_id": "c2", "job_id": "nope"})
    assert published(request(core, "cancel_job", again, 2.0)) == [
        error(0, "gridfleet/v1/requests/cancel_job", "CancelJob: unknown job 'nope'", "c2"),
        reply(2, "c2", False, "unknown job 'nope'", "nope", "unknown_job"),
    ]


def test_setting_a_goal_and_a_goal_on_a_wall(core: CoordinatorCore) -> None:
    goal = SetGoal(
        header=header("op"), request_id="g1", reply_to="op", unit="unit1", target=Cell(3, 2)
    )
    assert published(request(core, "set_goal", goal, 0.0)) == [reply(0, "g1", True, None, None)]
    assert core.directives.goals == {"unit1": (3, 2)}
    wall = goal.model_copy(update={"request_id": "g2", "target": (1, 1)})
    reason = "target [1, 1] is on a wall"
    assert published(request(core, "set_goal", wall, 0.0)) == [
        error(0, "gridfleet/v1/requests/set_goal", f"SetGoal: {reason}", "g2"),
        reply(1, "g2", False, reason, None, "bad_square"),
    ]


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (
            b'{"header": ',
            "SubmitJob: malformed JSON (Invalid JSON: EOF while parsing a value at line 1 column 11)",
        ),
        (b"{" * 20000, "SubmitJob: payload of 20000 bytes exceeds the limit of 16384"),
        (
            encode(submit(reply_to=None)).replace(b'"mass_kg":1.0', b'"mass_kg":0'),
            "SubmitJob: field 'mass_kg': Input should be greater than 0",
        ),
        (
            encode(submit()).replace(b'"reply_to":"op"', b'"reply_to":"a/b"'),
            "SubmitJob: field 'reply_to': String should match pattern '^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$'",
        ),
    ],
    ids=["malformed JSON", "oversized", "no reply_to", "bad reply_to"],
)
def test_a_bad_request_without_a_readable_reply_address_is_reported_only(
    core: CoordinatorCore, payload: bytes, reason: str
) -> None:
    effects = request(core, "submit_job", payload, 0.0)
    request_id = "r1" if b'"request_id":"r1"' in payload else None
    assert published(effects) == [error(0, "gridfleet/v1/requests/submit_job", reason, request_id)]
    assert core.jobs.jobs == {}


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (
            encode(submit()).replace(b'"1.6"', b'"2.0"'),
            "SubmitJob: field 'header.version': Value error, protocol version '2.0' is not '1.6'",
        ),
        (
            encode(submit()).replace(b'"mass_kg":1.0', b'"mass_kg":0'),
            "SubmitJob: field 'mass_kg': Input should be greater than 0",
        ),
        (
            encode(submit()).replace(b'"mass_kg":1.0', b'"mass_kg":"1.5"'),
            "SubmitJob: field 'mass_kg': Input should be a valid number",
        ),
    ],
    ids=["wrong version", "bad field", "number in a string"],
)
def test_a_bad_request_with_a_readable_reply_address_gets_its_refusal_as_a_reply(
    core: CoordinatorCore, payload: bytes, reason: str
) -> None:
    # The requester would otherwise wait for a reply that never comes.
    effects = request(core, "submit_job", payload, 0.0)
    assert published(effects) == [
        error(0, "gridfleet/v1/requests/submit_job", reason, "r1"),
        reply(0, "r1", False, reason, None, "invalid"),
    ]
    assert core.jobs.jobs == {}


@pytest.mark.parametrize(
    ("kind", "model", "payload"),
    [
        ("cancel_job", CancelJob, b"{"),
        ("cancel_job", CancelJob, b'{"header": {}, "request_id": "c1", "job_id": "a/b"}'),
        ("set_goal", SetGoal, b"{"),
        ("set_goal", SetGoal, b"x" * 20000),
    ],
    ids=["cancel JSON", "cancel fields", "goal JSON", "goal oversized"],
)
def test_a_bad_cancel_or_goal_is_reported_without_a_reply(
    core: CoordinatorCore, kind: str, model: type[Message], payload: bytes
) -> None:
    request(core, "submit_job", submit(), 0.0)
    effects = request(core, kind, payload, 0.5)
    topic = TOPICS.request(kind)
    request_id = "c1" if b'"request_id": "c1"' in payload else None  # named where readable
    assert published(effects) == [error(0, topic, codec_reason(model, payload), request_id)]
    assert core.jobs.jobs["job-1"].state == "queued" and core.directives.goals == {}


def codec_reason(model: type[Message], payload: bytes) -> str:
    """The reason the protocol's codec gives for refusing `payload` as `model`."""
    with pytest.raises(ProtocolError) as refused:
        decode(model, payload)
    return str(refused.value)


def codec_estop_reason(payload: bytes) -> str:
    """The reason the protocol's codec gives for refusing `payload` as an estop signal."""
    with pytest.raises(ProtocolError) as refused:
        decode_estop(payload)
    return str(refused.value)


@pytest.mark.parametrize(
    "topic",
    [
        "gridfleet/v1/units/unit1/order",  # ours, not one the coordinator reads
        "gridfleet/v1/fleet/nothing",
        "elsewhere/v1/requests/submit_job",
    ],
)
def test_a_topic_the_coordinator_does_not_read_is_ignored(
    core: CoordinatorCore, topic: str
) -> None:
    effects = core.on_message(topic, b"{", 0.0)
    assert published(effects) == [] and effects.log == () and core.errors_reported == 0


def test_a_burst_of_requests_gets_one_queue_view_per_period(core: CoordinatorCore) -> None:
    period = views_period_s(core.world.step_period_s)  # the step's: 1 s
    first = request(core, "submit_job", submit("r1"), 10.0)
    assert published(first)[-1] == jobs_view(1, job("queued"))
    second = request(core, "submit_job", submit("r2", job_id="j2"), 10.01)
    assert published(second) == [reply(1, "r2", True, None, "j2")]
    assert second.views_at == 10.0 + period  # come back at the end of the period
    third = request(core, "submit_job", submit("r3", job_id="j3"), 10.5)
    assert published(third) == [reply(2, "r3", True, None, "j3")]
    assert third.views_at is None  # already arranged
    later = core.views_due(10.0 + period)
    listed = [j["id"] for j in published(later)[0][1]["jobs"]]
    assert (published(later)[0][0], listed) == (JOBS, ["job-1", "j2", "j3"])
    # A full period after that, a request's view goes out at once again.
    fourth = request(core, "submit_job", submit("r4", job_id="j4"), 10.0 + 2 * period)
    assert [p[0] for p in published(fourth)] == [REPLY, JOBS]


def test_a_request_right_after_a_step_waits_for_the_next_period(core: CoordinatorCore) -> None:
    """The step's views count: the queue view goes out at most once a step, however many ask."""
    request(core, "submit_job", submit("r1"), 19.0)
    assert JOBS in [p[0] for p in published(core.step(20.0))]  # unit1 took the job: a new view
    effects = request(core, "submit_job", submit("r2", job_id="j2"), 20.1)
    assert JOBS not in [p[0] for p in published(effects)]
    assert effects.views_at == 20.0 + views_period_s(core.world.step_period_s)


# ---- a bug in the coordinator is reported, never fatal ---------------------------------------


def test_a_failure_on_one_message_is_reported_and_the_next_is_handled(
    core: CoordinatorCore, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(*_: object) -> None:
        raise KeyError("a bug")

    monkeypatch.setattr(core.world, "on_factsheet", broken)
    msg = Factsheet(header=header("unit1", seq=1), capacity_kg=3.0, step_period_s=0.5)
    effects = from_unit(core, "factsheet", "unit1", msg, 0.5)
    topic = TOPICS.unit("factsheet", "unit1")
    reason = "internal error in coordinator: KeyError while handling a message on this topic"
    assert published(effects) == [error(0, topic, reason)]  # the class alone: not 'a bug'
    assert effects.log[0][0] == logging.ERROR and "a bug" in effects.log[0][1]  # the log has it
    # Again within the second: held back, told with the next step once the second has passed.
    assert published(from_unit(core, "factsheet", "unit1", msg, 0.7)) == []
    assert published(from_unit(core, "factsheet", "unit1", msg, 0.8)) == []
    told = [p for p in published(core.step(1.6)) if p[0] == TOPICS.fleet("errors")]
    many = "internal error in coordinator: 2 failures (the latest KeyError) while handling"
    assert len(told) == 1 and many in told[0][1]["reason"] and topic in str(told[0][1])
    monkeypatch.undo()
    assert published(from_unit(core, "factsheet", "unit1", msg, 2.0)) == []


def test_a_failing_step_holds_every_unit_reports_it_and_the_next_step_runs(
    core: CoordinatorCore, monkeypatch: pytest.MonkeyPatch
) -> None:
    under_way(core)

    def broken(*_: object) -> None:
        raise RuntimeError("a bug")

    monkeypatch.setattr(core.progress, "advance", broken)
    effects = core.step(2.0)
    assert published(effects) == [
        (ORDER, hold(1, update_id=2, step=2), 1, False),
        # Its class alone, in the words the metric and the alert count (never its text).
        error(0, STATUS, failure_reason("coordinator", "RuntimeError")),
    ]
    monkeypatch.undo()
    assert any(o.topic == ROUTES for o in core.step(3.0).publish)


def test_a_press_cleared_while_its_latch_copy_is_on_its_way_releases_without_failing(
    core: CoordinatorCore,
) -> None:
    # The soak saw this after a coordinator restart: the retained latch said released, a
    # device's press said engaged, and the press's clearing (sent by the coordinator before
    # it restarted) came next. The coordinator failed on it with an AssertionError.
    press = "gridfleet/v1/devices/dev1/stop"
    estop(core, b"released|dashboard|checked")
    core.on_message(press, b"engaged|dev1|button", 1.5)
    effects = core.on_message(press, b"", 1.6)
    assert effects.log == ((logging.WARNING, "emergency stop released: dev1's press was cleared"),)
    assert published(effects)[-1] == (STATUS, status(1, "online", step=0, estop=False), 1, True)


def test_a_press_the_broker_lost_while_the_latch_says_released_is_latched_after_reconnecting(
    core: CoordinatorCore,
) -> None:
    # Found by the 30-minute soak: the coordinator kept a press the restarted broker no longer
    # had, under a retained `released` latch. It held the fleet, and no release could clear it
    # (a release is only a latch going from engaged to released). Latched, it can be released.
    estop(core, b"released|operator|earlier")
    press(core, b"engaged|dev1|button")  # mirrored into the latch ...
    core.on_connect(10.0)  # ... but the broker restarted before that came back
    estop(core, b"released|operator|earlier", 10.1)  # the replay: the latch, no press
    assert core.estop
    effects = core.step(11.0)
    assert published(effects)[0] == (ESTOP, "engaged|dev1|button", 1, True)
    assert (logging.WARNING, "emergency stop re-asserted on the broker (dev1)") in effects.log
    estop(core, b"engaged|dev1|button", 11.1)  # it comes back
    released = estop(core, b"released|operator|checked", 12.0)
    assert (PRESS, "", 1, True) in published(released)  # the press is cleared with it
    assert not core.estop


def test_a_press_the_broker_replays_is_not_latched_again(core: CoordinatorCore) -> None:
    estop(core, b"engaged|dev1|button")
    press(core, b"engaged|dev1|button")
    core.on_connect(10.0)
    estop(core, b"engaged|dev1|button", 10.1)
    press(core, b"engaged|dev1|button")
    assert ESTOP not in [o.topic for o in core.step(12.0).publish]


def test_a_unit_of_another_map_left_on_the_broker_is_ignored_and_said_once(
    core: CoordinatorCore,
) -> None:
    # Issue 18: a playfield run's retained unit3 and unit4 (state, offline connection) were taken
    # into the warehouse run's world on the same root; its routes held, 2.8 steps/s.
    other = Factsheet(
        header=header("unit9"), capacity_kg=5.0, step_period_s=1.0, map_id="0123456789ab"
    )
    first = from_unit(core, "factsheet", "unit9", other, 1.0)
    assert first.log == (
        (
            logging.WARNING,
            f"unit unit9 drives on another map (0123456789ab, ours {core.world.map_id}): ignored",
        ),
    )
    assert from_unit(core, "factsheet", "unit9", other, 1.1).log == ()  # said once
    offline = Connection(header=header("unit9"), state="offline")
    assert published(from_unit(core, "connection", "unit9", offline, 1.2)) == []
    assert "unit9" not in core.world.units
    ours = other.model_copy(update={"map_id": core.world.map_id})
    from_unit(core, "factsheet", "unit9", ours, 2.0)  # a unit of this map under that id
    assert "unit9" in core.world.units


def test_an_operator_clears_obstacles_that_are_gone_and_a_typo_changes_nothing(
    core: CoordinatorCore,
) -> None:
    seen = Sensors(N="wall", E="free", S="obstacle", W="wall")
    drive(core, state(Cell(0, 0), seq=1, obstacles=[Cell(0, 1)], sensors=seen))
    assert core.world.obstacles == {Cell(0, 1)}

    def clear(rid: str, squares: list[list[int]] | None) -> list[Any]:
        req = ClearObstacles(header=header("op"), request_id=rid, reply_to="op", squares=squares)
        return [
            m
            for m in published(request(core, "clear_obstacles", req, 2.0))
            if "/fleet/" not in m[0]
        ]

    typo = clear("c1", [[3, 2]])
    assert typo[-1][1]["accepted"] is False
    assert typo[-1][1]["reason"] == "[3, 2] is not a discovered obstacle (known: [0, 1])"
    assert core.world.obstacles == {Cell(0, 1)}
    assert clear("c2", [[0, 1]])[-1][1]["accepted"] is True
    assert core.world.obstacles == set() and core.world.grid.is_free(Cell(0, 1))
    assert core.views.map_dirty  # the map view goes out with the next views


@pytest.mark.parametrize(
    ("squares", "words"),
    [
        ("[]", "field 'squares': List should have at least 1 item"),
        ('"all"', "field 'squares'"),
        ("[[-1, 0]]", "field 'squares"),
    ],
)
def test_a_malformed_clear_obstacles_is_refused_in_words_and_clears_nothing(
    core: CoordinatorCore, squares: str, words: str
) -> None:
    seen = Sensors(N="wall", E="free", S="obstacle", W="wall")
    drive(core, state(Cell(0, 0), seq=1, obstacles=[Cell(0, 1)], sensors=seen))
    head = json.dumps(
        {"version": "1.6", "seq": 0, "timestamp": "2026-11-21T10:00:00Z", "sender": "op"}
    )
    raw = f'{{"header": {head}, "request_id": "c9", "reply_to": "op", "squares": {squares}}}'
    out = published(core.on_message(TOPICS.request("clear_obstacles"), raw.encode(), 2.0))
    replies = [body for topic, body, *_ in out if topic.endswith("/replies/op")]
    assert len(replies) == 1 and replies[0]["accepted"] is False, out
    assert replies[0]["reason"].startswith("ClearObstacles: ") and words in replies[0]["reason"]
    assert core.world.obstacles == {Cell(0, 1)}
