"""A unit's motion judged by the fleet's own clock and step period, never by the unit's word alone.

Issue 51, point 4: one-square states were accepted at any rate, a unit's factsheet set its own
allowance, and a unit back from a silence "delivered" its job without standing on the pickup.
Pure core tests (exact publishes, as test_coordinator_effects.py), then one over a real broker.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest
from test_coordinator_effects import state as effects_state

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import ErrorReport, Sensors, SubmitJob, Topics, UnitState, decode
from gridfleet.system.broker_thread import BrokerThread

from support.coordinator_drive import from_unit, make_core, meet, request
from support.effects import header, header_json, published
from support.probe import MqttProbe
from support.wait import async_wait_for

CORRIDOR = GridMap.from_rows(["." * 16])  # one row: [0, 0] to [15, 0]
ROOM = GridMap.from_rows(["....", ".@..", "...."])  # four by three, a wall at [1, 1]
ERRORS = "gridfleet/v1/errors"
STATE = "gridfleet/v1/units/unit1/state"


CORRIDOR_SENSORS = Sensors(N="wall", E="free", S="wall", W="free")


def state(position: Cell, seq: int = 0, **over: Any) -> UnitState:
    """unit1's state: idle on `position` of the corridor, its step counter `seq`."""
    return effects_state(position, seq, **{"sensors": CORRIDOR_SENSORS, **over})


def error(seq: int, reason: str) -> Any:
    """The coordinator's report of a refused state of unit1."""
    payload = {
        "header": header_json("coordinator", seq),
        "topic": STATE,
        "reason": reason,
        "request_id": None,
    }
    return (ERRORS, payload, 1, False)


def corridor(fleet_step_s: float, factsheet_step_s: float) -> CoordinatorCore:
    """A core on the corridor whose unit1 stands on [0, 0] (heard at 0 s)."""
    core = make_core(CORRIDOR, step_s=fleet_step_s)
    core.on_connect()
    meet(core, state(Cell(0, 0)), capacity_kg=5.0, step_s=factsheet_step_s)
    return core


@pytest.mark.parametrize("factsheet_step_s", [0.2, 0.01], ids=["as-the-fleet", "claims-faster"])
def test_one_square_states_faster_than_the_fleet_drives_are_refused(
    factsheet_step_s: float,
) -> None:
    # As found: 13 one-square states in 0.07 s at a 0.2 s step, every one accepted. The fleet's
    # step period sets the pace, whatever the factsheet claims: a square every 0.2 s, with a slack
    # of 7 squares (its window of 1, a step caught up, and a second of states arriving at once).
    core = corridor(0.2, factsheet_step_s)
    got = [
        published(from_unit(core, "state", "unit1", state(Cell(x, 0), seq=x), 0.3 + 0.005 * x))
        for x in range(1, 14)
    ]
    assert got[:8] == [[]] * 8
    assert got[8] == [
        error(
            0,
            "position [9, 0] at step 9 is 1 square from [8, 0] at step 8, the last state "
            "accepted 0.01 s before: faster than unit unit1 can drive (at most 0.2 squares by "
            "now: a square every 0.20 s, the fleet's step period, with a slack of 7 squares)",
        )
    ]
    # Each later one is further still from the last square accepted: refused too.
    assert [[m[1]["topic"] for m in g] for g in got[9:]] == [[STATE]] * 4
    assert core.world.units["unit1"].position == Cell(8, 0)  # the refused ones changed nothing
    # Driven at the fleet's pace, the unit goes on from where it was last accepted.
    for x in range(9, 14):
        at_pace = 0.34 + 0.2 * (x - 8)
        assert published(from_unit(core, "state", "unit1", state(Cell(x, 0), seq=x), at_pace)) == []
    assert core.world.units["unit1"].position == Cell(13, 0)


def test_a_slow_units_factsheet_buys_it_no_jump_after_a_silence() -> None:
    # As found: a factsheet of step_period_s = 60 kept a silent unit from counting as lost, and
    # the unit then jumped 14 squares after 4 s of silence. Its own factsheet may make a unit
    # slower than the fleet, never faster: a square a minute, after 4 s, is its slack alone.
    core = corridor(0.2, 60.0)
    assert published(from_unit(core, "state", "unit1", state(Cell(14, 0), seq=14), 4.0)) == [
        error(
            0,
            "position [14, 0] at step 14 is 14 squares from [0, 0] at step 0, the last state "
            "accepted 4.00 s before: faster than unit unit1 can drive (at most 7.1 squares by "
            "now: a square every 60.00 s, the step period of its factsheet, with a slack of 7 "
            "squares)",
        )
    ]
    assert core.world.units["unit1"].position == Cell(0, 0)
    # Its slack spent, it drives at the pace its factsheet gives: a square a minute.
    for x in range(1, 8):
        assert published(from_unit(core, "state", "unit1", state(Cell(x, 0), seq=x), 4.5)) == []
    late = published(from_unit(core, "state", "unit1", state(Cell(8, 0), seq=8), 5.0))
    assert "faster than unit unit1 can drive" in late[0][1]["reason"]
    assert published(from_unit(core, "state", "unit1", state(Cell(8, 0), seq=8), 65.0)) == []


def test_a_window_released_ahead_may_be_driven_at_once() -> None:
    # A VDA 5050 vehicle drives its whole base at its own speed: a unit the fleet gives a window
    # of 4 squares ahead (it ran dry waiting for orders) may report the 4 in one go, and keeps
    # going at 4 squares a step. Simulated units at their normal rate are refused nothing.
    core = corridor(0.2, 0.2)
    core.orders.track("unit1").reach = 4
    now = 1.0
    for x in range(1, 15):  # 14 squares in 0.7 s: 4 a step (0.8 s) with the slack
        now += 0.05
        assert published(from_unit(core, "state", "unit1", state(Cell(x, 0), seq=x), now)) == []
    assert core.world.units["unit1"].position == Cell(14, 0)


def _assigned_unit_lost() -> CoordinatorCore:
    """unit1 given job-1 (pickup [3, 0]), one square on its way, then silent until it is lost."""
    core = make_core(ROOM)
    core.on_connect()
    meet(core, state(Cell(0, 0)), capacity_kg=5.0)
    job: dict[str, Any] = {"pickup": [3, 0], "dropoff": [3, 2], "mass_kg": 1.0, "priority": 0}
    sub = SubmitJob(header=header("op"), request_id="r1", reply_to="op", **job)
    request(core, "submit_job", sub, 0.0)
    core.step(1.0)
    assert published(from_unit(core, "state", "unit1", state(Cell(1, 0), seq=1), 1.5)) == []
    core.step(10.0)  # 8.5 s silent (states came 1.5 s apart: lost after 7.5 s): re-queued
    found = core.jobs.jobs["job-1"]
    assert (found.state, found.unit, found.reason) == (
        "queued",
        None,
        "unit unit1 was lost; re-queued",
    )
    return core


def test_a_unit_back_from_a_silence_naming_its_job_away_from_the_pickup_has_not_picked_it() -> None:
    # As found: silent 1.6 s, back naming the job it was given, then a fast chain to the dropoff:
    # "done by unit1 in 28.0 s", the pickup never visited. A pickup counts only where it is made.
    core = _assigned_unit_lost()
    claim = state(Cell(2, 0), seq=2, job_id="job-1", load_kg=1.0)  # one square on: a rejoin
    assert published(from_unit(core, "state", "unit1", claim, 10.5)) == []
    core.step(11.0)
    found = core.jobs.jobs["job-1"]
    assert (found.state, found.unit) == ("queued", None)
    # Nor does walking on to the pickup afterwards make the claim a pickup.
    at_pickup = state(Cell(3, 0), seq=3, job_id="job-1", load_kg=1.0)
    assert published(from_unit(core, "state", "unit1", at_pickup, 11.5)) == []
    core.step(12.0)
    assert core.jobs.jobs["job-1"].state == "queued"


def test_a_unit_back_from_a_silence_seen_picking_at_the_pickup_carries_on() -> None:
    # The other side: back on the pickup with the item (it picked it up unheard), it has it.
    core = _assigned_unit_lost()
    assert published(from_unit(core, "state", "unit1", state(Cell(2, 0), seq=2), 10.5)) == []
    picked = state(Cell(3, 0), seq=3, job_id="job-1", load_kg=1.0)
    assert published(from_unit(core, "state", "unit1", picked, 11.5)) == []
    core.step(12.0)
    found = core.jobs.jobs["job-1"]
    assert (found.state, found.unit) == ("loaded", "unit1")


# ---- over a real broker -----------------------------------------------------------------------


@pytest.mark.every_broker
async def test_states_faster_than_the_fleet_drives_are_refused_over_the_broker(
    broker: BrokerThread, root: str, tmp_path: Path
) -> None:
    topics = Topics(root)
    shell = CoordinatorShell(broker.url, CORRIDOR, root=root, step_s=0.2, db_path=tmp_path / "db")
    stop = asyncio.Event()
    task = asyncio.create_task(shell.run(stop))
    await asyncio.wait_for(shell.ready.wait(), 10)
    probe = MqttProbe(broker.url, f"{root}-unit1").connect()
    probe.subscribe(topics.fleet("errors"), qos=1)
    hdr = {"version": "1.6", "seq": 0, "timestamp": "2026-11-21T10:00:00Z", "sender": "unit1"}

    def publish(kind: str, body: dict[str, Any]) -> None:
        probe.publish(topics.unit(kind, "unit1"), json.dumps({"header": hdr, **body}).encode())

    def at(x: int) -> dict[str, Any]:
        sensors = {"N": "wall", "E": "free", "S": "wall", "W": "free"}
        return {
            "step": x,
            "position": [x, 0],
            "direction": "-",
            "status": "idle",
            "leds": {},
            "sensors": sensors,
        }

    try:
        publish("connection", {"state": "online"})
        publish("factsheet", {"capacity_kg": 5.0, "step_period_s": 0.2})
        publish("state", at(0))
        await async_wait_for(
            lambda: shell.world.units.get("unit1") and shell.world.units["unit1"].position,
            what="unit1 heard on [0, 0]",
        )
        unit = shell.world.units["unit1"]
        with probe.batch():  # 13 one-square states back to back
            for x in range(1, 14):
                publish("state", at(x))
        reports = await async_wait_for(
            lambda: probe.received(topics.fleet("errors")), what="the refusal"
        )
        report = decode(ErrorReport, reports[0].payload)
        assert report.topic == topics.unit("state", "unit1")
        assert "faster than unit unit1 can drive" in report.reason, report.reason
        await async_wait_for(lambda: shell.core.errors_reported >= 1, what="counted")
        assert unit.position is not None and unit.position.x < 13
        assert not task.done()
    finally:
        probe.close()
        stop.set()
        await asyncio.wait_for(task, 10)
