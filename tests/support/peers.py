"""The coordinator as units see it, for tests that drive real units over a real broker.

`DispatchPeer` is a `CoordinatorPeer` (what the coordinator publishes, `support.fleet_peer`) that
also plays its side of protocol.md §4.4 towards units: it sends orders (and, as an operator
would, goals), engages or releases the emergency stop, announces the step period units size their
hold timeout by, and reads what the units publish (states, directions, connections, error
reports) with the protocol's own decoders (`support.readers.FleetReader`). Every message is built from the protocol's models,
stamped by its sender, and published with the QoS and retain flag protocol.md gives its topic.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from gridfleet.grid import Cell
from gridfleet.protocol import (
    Action,
    EstopSignal,
    Goal,
    Order,
    Topics,
    UnitState,
    encode_estop,
)

from support.fleet_peer import CoordinatorPeer, publish
from support.probe import MqttProbe
from support.readers import FleetReader
from support.wait import async_wait_for


class DispatchPeer(CoordinatorPeer, FleetReader):
    """Sends units orders, its status and the stop; reads their states, connections and errors.

    It subscribes on creation, so whatever units publish afterwards is kept by its probe. With a
    `step_period_s` it announces that (retained) status at once; None announces nothing.
    """

    def __init__(
        self,
        probe: MqttProbe,
        topics: Topics,
        step_period_s: float | None = 5.0,
        sender: str = "coordinator",
    ) -> None:
        super().__init__(probe, topics, sender)
        self.step_period_s = step_period_s
        for kind in ("state", "direction"):
            probe.subscribe(topics.all_units(kind), qos=0)  # high rate: QoS 0 (protocol §2)
        probe.subscribe(topics.all_units("connection"), qos=1)
        probe.subscribe(topics.fleet("errors"), qos=1)
        if step_period_s is not None:
            self.status(step_period_s=step_period_s)

    # ---- what it sends ----------------------------------------------------------------------

    def order(
        self,
        unit: str,
        oid: str,
        update: int,
        released: Sequence[tuple[int, int]],
        planned: Sequence[tuple[int, int]] = (),
        action: Action | None = None,
    ) -> Order:
        """Release `released` to `unit` under order `oid`, update `update` (squares as (x, y))."""
        order = Order(
            header=self.stamp("order"),
            order_id=oid,
            update_id=update,
            released=[Cell(*square) for square in released],
            planned=[Cell(*square) for square in planned],
            action=action,
        )
        publish(self.probe, "order", self.topics.unit("order", unit), order)
        return order

    def raw_order(self, unit: str, payload: bytes) -> None:
        """Send `unit` any bytes as an order (to see it refuse them)."""
        publish(self.probe, "order", self.topics.unit("order", unit), payload)

    def goal(self, unit: str, target: Cell | None) -> Goal:
        """Give a standalone `unit` a goal, as an operator would (None clears it)."""
        goal = Goal(header=self.stamp("goal"), target=target)
        publish(self.probe, "goal", self.topics.unit("goal", unit), goal)
        return goal

    def raw_goal(self, unit: str, payload: bytes) -> None:
        """Send `unit` any bytes as a goal."""
        publish(self.probe, "goal", self.topics.unit("goal", unit), payload)

    def estop(self, engaged: bool, payload: bytes | None = None) -> None:
        """Engage or release the retained stop; `payload` sends those bytes instead."""
        data = payload or encode_estop(EstopSignal(engaged, "tester", "test"))
        publish(self.probe, "estop", self.topics.fleet("estop"), data)

    # ---- what it reads (and, from FleetReader, states, directions, connections, errors) -------

    async def until_state(
        self,
        unit: str,
        match: Callable[[UnitState], bool],
        what: str = "state",
        timeout: float = 10,
    ) -> UnitState:
        """The latest state of `unit` that `match`es (waits for one to arrive)."""

        def find() -> UnitState | None:
            return next((s for s in reversed(self.states(unit)) if match(s)), None)

        found = await async_wait_for(find, timeout, what=f"{unit} {what}")
        assert found is not None
        return found
