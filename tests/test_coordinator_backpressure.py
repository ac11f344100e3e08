"""The coordinator does not step ahead of units that have not acknowledged their last moves."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path

from gridfleet.protocol import (
    Connection,
    Factsheet,
    HeaderStamper,
    Leds,
    Routes,
    Sensors,
    SubmitJob,
    Topics,
    UnitState,
    decode,
    encode,
)
from gridfleet.protocol.constants import MAX_VIEW_BYTES
from gridfleet.scenario import load_scenario
from system.broker_thread import BrokerThread
from system.threads import coordinator_thread

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
    unit = probe_factory()
    stamp = HeaderStamper("unit1")
    order_topic = topics.unit("order", "unit1")
    unit.subscribe(order_topic)
    unit.subscribe(topics.fleet("routes"), qos=0)
    unit.publish(
        topics.unit("connection", "unit1"),
        encode(Connection(header=stamp("connection"), state="online")),
        retain=True,
    )
    unit.publish(
        topics.unit("factsheet", "unit1"),
        encode(Factsheet(header=stamp("factsheet"), capacity_kg=5, step_period_s=STEP)),
        retain=True,
    )
    acked: dict[str, object] = {"order_id": None, "update_id": 0}
    stop = threading.Event()

    frozen = threading.Event()

    def heartbeat() -> None:
        # A unit whose states keep coming; it acknowledges holds at once, but once a move has
        # come it acknowledges only what `acked` says (a unit whose acks are late).
        while not stop.is_set():
            orders = [json.loads(m.payload) for m in unit.received(order_topic)]
            if any(o["released"] for o in orders):
                frozen.set()
            if orders and not frozen.is_set():
                acked.update(order_id=orders[-1]["order_id"], update_id=orders[-1]["update_id"])
            state = UnitState(
                header=stamp("state"),
                step=0,
                position=(0, 0),  # type: ignore[arg-type]
                direction="-",
                status="idle",
                leds=Leds(),
                sensors=Sensors(N="wall", E="free", S="free", W="wall"),
                order_id=acked["order_id"],  # type: ignore[arg-type]
                order_update_id=acked["update_id"],  # type: ignore[arg-type]
            )
            unit.client.publish(topics.unit("state", "unit1"), encode(state), qos=0)
            stop.wait(STEP)

    beat = threading.Thread(target=heartbeat, daemon=True)
    beat.start()

    def steps() -> int:
        seen = unit.received(topics.fleet("routes"))
        return decode(Routes, seen[-1].payload, MAX_VIEW_BYTES).step if seen else 0

    scenario = load_scenario(playfield)
    try:
        with coordinator_thread(
            scenario, broker.url, root=root, step_s=STEP, db_path=tmp_path / "jobs.db"
        ):
            wait_for(lambda: steps() > 0, timeout=10, what="coordinator steps")
            operator = probe_factory()
            job = SubmitJob(
                header=HeaderStamper("op")("submit_job"),
                request_id="r1",
                pickup=(5, 0),  # type: ignore[arg-type]
                dropoff=(9, 0),  # type: ignore[arg-type]
                mass_kg=1.0,
            )
            operator.publish(topics.request("submit_job"), encode(job))

            def first_move() -> dict[str, object] | None:
                for m in unit.received(order_topic):
                    order = json.loads(m.payload)
                    if order["released"]:
                        return order  # type: ignore[no-any-return]
                return None

            move = wait_for(first_move, timeout=10, what="a released move")
            assert move is not None
            # Not acknowledged: the coordinator slows to one step per ACK_WAIT_S (0.25 s).
            start, t0 = steps(), time.monotonic()
            wait_for(lambda: time.monotonic() - t0 >= 1.0, timeout=5, interval=0.05)
            slow = steps() - start
            assert slow <= 8, f"{slow} steps in 1 s while the move was not acknowledged"
            # Acknowledged: back to its own period.
            acked.update(order_id=move["order_id"], update_id=move["update_id"])
            start, t0 = steps(), time.monotonic()
            wait_for(lambda: steps() - start >= 3 * slow + 10, timeout=10, what="fast steps")
    finally:
        stop.set()
        beat.join(2)
