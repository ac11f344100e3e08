"""Coordinated driving (protocol.md §4.4): taking orders, following released squares, the action."""

from __future__ import annotations

from gridfleet.grid import Cell, GridMap
from gridfleet.protocol.messages import Action, Order
from gridfleet.robots.decisions import THING, Intent, Readings, Verdict, sq


def check_route(grid: GridMap, here: Cell, released: list[Cell]) -> str | None:
    """Why `released` cannot be driven from `here` (off the map, a wall, a gap), or None."""
    for i, cell in enumerate(released):
        if not grid.in_bounds(cell):
            return f"released square {sq(cell)} is off the {grid.width}x{grid.height} map"
        if not grid.is_free(cell):
            return f"released square {sq(cell)} is a wall"
        if here.manhattan(cell) != 1:
            before = "the unit's square" if i == 0 else "the square before it"
            return f"released square {sq(cell)} is not adjacent to {before} {sq(here)}"
        here = cell
    return None


class OrderFollower:
    """The order a coordinated unit follows: ids, released squares not yet driven, action, charger."""

    def __init__(self, grid: GridMap) -> None:
        self.grid = grid
        self.order_id: str | None = None
        self.update_id = 0
        self.released: list[Cell] = []
        self.action: Action | None = None
        self.charge: Cell | None = None  # where the current order has it charge (rule 8)
        self._acted: tuple[str | None, str] | None = None  # (order, action) done last

    def take(self, order: Order, position: Cell) -> Verdict:
        """Accept `order` from `position`, or say it is stale or refused (and then change nothing)."""
        if order.order_id == self.order_id and order.update_id <= self.update_id:
            return Verdict("stale")
        released = list(order.released)
        if position in released:
            # The unit already drove the leading squares (the order was planned from an older
            # state): it follows on from where it stands.
            released = released[released.index(position) + 1 :]
        problem = check_route(self.grid, position, released)
        if problem is None and order.action is not None:
            square = order.action.square
            if not self.grid.is_free(square):
                problem = f"action square {sq(square)} is off the map or on a wall"
        if problem is not None:
            return Verdict(
                "refused", f"order {order.order_id!r} update {order.update_id}: {problem}"
            )
        self.order_id = order.order_id
        self.update_id = order.update_id
        self.released = released
        self.action = order.action
        self.charge = order.charge
        return Verdict("accepted")

    def drop(self) -> None:
        """Forget the released squares not yet driven (holding, the stop); the next order releases.

        The charger is kept: standing where it stands, the unit may charge on (not while stopped:
        `UnitLogic.charging`), and the next order says again whether it is to.
        """
        self.released = []

    def next_move(self, position: Cell, sensors: Readings) -> Intent:
        """Into the next released square if the unit's own sensor sees it free; else wait or idle."""
        if not self.released:
            return Intent(None, "idle")
        nxt = self.released[0]
        d = position.direction_to(nxt)
        if d is None:  # cannot happen: orders are checked to be contiguous
            self.released = []
            return Intent(None, "idle")
        reading = sensors[d]
        if reading != "free":
            return Intent(
                None, "waiting", f"released square {sq(nxt)} is blocked by {THING[reading]}"
            )
        return Intent(d, "moving")

    def arrived(self, position: Cell) -> None:
        """The unit now stands on `position`: a released square it reached is driven."""
        if self.released and self.released[0] == position:
            self.released.pop(0)

    def action_due(self, position: Cell) -> Action | None:
        """The order's action, once, when the unit stands on its square with nothing left to drive."""
        a = self.action
        if a is None or self.released or position != a.square:
            return None
        key = (self.order_id, f"{a.kind}:{a.job_id}")
        if self._acted == key:
            return None  # repeating an action already done changes nothing (rule 5)
        self._acted = key
        return a
