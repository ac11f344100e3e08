"""Orders a vehicle refused, pure: when the order ends here and when the vehicle is given up.

The spec lets a vehicle refuse an update (`orderUpdateError`) or a route (`noRouteError`); it then
finishes what it had accepted and stops. Once it has, the order ends (the core drops what it
refused). A vehicle that refuses REFUSALS_TO_GIVE_UP new orders in a row, and says so still,
counts as unable to drive (`unroutable`).
"""

from __future__ import annotations

from gridfleet.robots.vda5050.inbound import VdaState

REFUSALS = {"orderUpdateError", "noRouteError"}
REFUSALS_TO_GIVE_UP = 3


def refuses(message: VdaState) -> bool:
    """Whether a state reports an order or an update refused (any order's)."""
    return any(e.errorType in REFUSALS for e in message.errors)


class Refusals:
    """New orders refused in a row, and whether the vehicle refuses every route."""

    def __init__(self) -> None:
        self.in_a_row = 0  # new orders refused in a row (noRouteError, orderUpdateError)
        self.unroutable = False

    def read(self, message: VdaState, ours: str | None, nodes_left: int) -> list[str]:
        """What the vehicle refused of order `ours`, once it stopped on what it accepted; else []."""
        # An error naming another order is about one gone by (a state older than our order).
        refused = {
            e.errorType
            for e in message.errors
            if e.errorType in REFUSALS and e.about("orderId") in (None, ours)
        }
        if not refused:
            if not refuses(message):
                self.in_a_row = 0
                self.unroutable = False
            return []
        if ours is None or message.driving or nodes_left:
            return []  # still on what it accepted
        if message.orderId != ours:
            self.in_a_row += 1  # it never took the current order
        self.unroutable = self.in_a_row >= REFUSALS_TO_GIVE_UP
        return sorted(refused)
