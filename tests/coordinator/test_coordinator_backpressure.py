"""The coordinator does not step ahead of units that have not acknowledged their last moves."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

from gridfleet.coordinator.orders import OrderPlan, Orders
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import Order, Routes, Sensors, Topics, decode
from gridfleet.protocol.constants import MAX_VIEW_BYTES
from gridfleet.robots.unit import UnitLogic
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import coordinator_thread

from support.effects import header
from support.fleet_peer import UnitPeer
from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.wait import wait_for

STEP = 0.02


def test_steps_wait_for_acknowledgements_of_moves(
    broker: BrokerThread,
    root: str,
    topics: Topics,
    tmp_path: Path,
    playfield: Path,
    probe_factory: Callable[..., MqttProbe],
) -> None:
    unit = UnitPeer(probe_factory(), topics, "unit1")
    unit.follow_orders()
    unit.probe.subscribe(topics.fleet("routes"), qos=0)
    unit.connection("online")
    unit.factsheet(5, step_period_s=STEP)
    acked: tuple[str | None, int] = (None, 0)  # the order id and update id the unit acknowledges
    stop = threading.Event()

    frozen = threading.Event()

    def heartbeat() -> None:
        # A unit whose states keep coming; it acknowledges halt orders at once, but once a move has
        # come it acknowledges only what `acked` says (a unit whose acks are late).
        nonlocal acked
        while not stop.is_set():
            orders = unit.orders()
            if any(o.released for o in orders):
                frozen.set()
            if orders and not frozen.is_set():
                acked = (orders[-1].order_id, orders[-1].update_id)
            unit.state(
                Cell(0, 0),
                step=0,
                sensors=Sensors(N="wall", E="free", S="free", W="wall"),
                order_id=acked[0],
                order_update_id=acked[1],
            )
            stop.wait(STEP)

    beat = threading.Thread(target=heartbeat, daemon=True)
    beat.start()

    def steps() -> int:
        seen = unit.probe.received(topics.fleet("routes"))
        return decode(Routes, seen[-1].payload, MAX_VIEW_BYTES).step if seen else 0

    scenario = load_scenario(playfield)
    try:
        with coordinator_thread(
            scenario, broker.url, root=root, step_s=STEP, db_path=tmp_path / "jobs.db"
        ):
            wait_for(lambda: steps() > 0, timeout=10, what="coordinator steps")
            operator = OperatorPeer(probe_factory(), topics, "op")
            assert operator.submit_job(Cell(5, 0), Cell(9, 0), 1.0).accepted

            def first_move() -> Order | None:
                return next((o for o in unit.orders() if o.released), None)

            move = wait_for(first_move, timeout=10, what="a released move")
            assert move is not None
            # Not acknowledged: the coordinator slows to one step per ACK_WAIT_S (0.25 s).
            start, t0 = steps(), time.monotonic()
            wait_for(lambda: time.monotonic() - t0 >= 1.0, timeout=5, interval=0.05)
            slow = steps() - start
            assert slow <= 8, f"{slow} steps in 1 s while the move was not acknowledged"
            # Acknowledged: back to its own period.
            acked = (move.order_id, move.update_id)
            start, t0 = steps(), time.monotonic()
            wait_for(lambda: steps() - start >= 3 * slow + 10, timeout=10, what="fast steps")
    finally:
        stop.set()
        beat.join(2)


def test_a_few_late_units_do_not_hold_back_the_steps_of_the_rest() -> None:
    # bench system, 100 units: each step waited for the slowest unit's acknowledgement.
    orders = Orders("n")
    grid = GridMap.from_rows(["." * 20])

    def step(units: int, acking: int) -> bool:
        plans = {}
        for i in range(units):  # each unit's squares changed in update 1 of a fresh order
            track = orders.track(f"u{i}")
            track.order_id, track.update_id, track.content_update = f"n-u{i}", 1, 1
            track.acked_update = 0
            plans[f"u{i}"] = OrderPlan(f"n-u{i}", 1, 1, [Cell(i, 0)], [], None, None)
        orders.expect(plans)
        for i in range(acking):
            state = UnitLogic(f"u{i}", grid, Cell(i, 0), 1.0, 1.0).report(header(f"u{i}"))
            orders.heard(
                f"u{i}", state.model_copy(update={"order_id": f"n-u{i}", "order_update_id": 1})
            )
        return orders.holding_back

    assert step(20, 0) and step(20, 13)  # seven of twenty late: wait (a while)
    assert not step(20, 14) and not step(20, 20)  # six late: they get no squares meanwhile
    assert step(1, 0) and not step(1, 1)  # one unit: it is the fleet
    # A heartbeat (the same squares again, acknowledged) is not awaited.
    orders.expect({"u0": OrderPlan("n-u0", 2, 2, [Cell(0, 0)], [], None, None)})
    assert orders.awaiting == {}
