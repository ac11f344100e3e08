"""A VDA 5050 vehicle's `state`, read for the fleet: where it stands and whether it may drive.

The state arrives validated against the official schema of the vehicle's version (the adapter's
shell does that at the edge); here it is read, pure.

Where it stands, safely. gridfleet reserves a unit's square until the unit's state shows it left,
and the square ahead is reserved for the unit by being released to it (protocol.md §4.4). A
vehicle moves continuously, so its reported square is the one it is leaving for as long as any
part of it (its position, its body beyond that point, its position's deviation) may still be on
it, and only then the next square of its base: between two squares it holds both, the one behind
as its square and the one ahead as released. This holds whatever the state interval (30 s is
allowed) and if states are lost (QoS 0): a square is given up only on a state that shows the
vehicle off it, never for want of one.

What the schemas leave optional, and what is assumed without it (docs/vda5050.md lists them):
no `agvPosition`, where it stands is unknown (no square); no `deviationRange`, the position is
exact, and a negative one is read by its size; no `paused`, not paused; an error without
`errorDescription` is told by its type alone. A position off the grid, or a deviation reaching
beyond it, holds only the grid's squares (`within`): no state costs more than the grid.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from gridfleet.grid import Cell
from gridfleet.robots.vda5050.frame import Frame


def reported_square(
    previous: Cell | None, under: frozenset[Cell], base: Sequence[Cell]
) -> Cell | None:
    """The square to report for a vehicle now on the squares `under`, after `previous`.

    The previous square while the vehicle may still be on it; else the first square of the base
    beyond the previous one that it is on; else, with nothing to go by, the one square it is on.
    None when that is not one square (it is somewhere the fleet did not send it): the adapter
    then says so, and the vehicle holds.
    """
    if previous is not None and previous in under:
        return previous
    start = 0
    if previous is not None and previous in base:
        start = len(base) - 1 - list(base)[::-1].index(previous)
    ahead = [cell for cell in list(base)[start:] if cell in under]
    if ahead:
        return ahead[0]
    return next(iter(under)) if len(under) == 1 else None


@dataclass(frozen=True)
class VehicleView:
    """What the fleet needs from one vehicle state."""

    under: frozenset[Cell]  # every square the vehicle may be on (empty: position unknown)
    driving: bool
    paused: bool
    automatic: bool  # operatingMode AUTOMATIC: only then does it follow orders
    estop: bool  # its own emergency stop (safetyState.eStop other than NONE): a press
    fatal: tuple[str, ...]  # FATAL errors: it cannot run
    warnings: tuple[str, ...]
    battery_pct: float
    charging: bool
    errors: tuple[str, ...]  # every error it reports, as `LEVEL errorType: errorDescription`
    last_node: tuple[str, int]  # lastNodeId, lastNodeSequenceId
    finished: frozenset[str]  # action ids FINISHED
    failed: frozenset[str]  # action ids FAILED
    running: frozenset[str] = frozenset()  # action ids INITIALIZING or RUNNING
    listed: frozenset[str] = frozenset()  # every action id it lists, in any status

    @property
    def can_drive(self) -> bool:
        """Whether the vehicle counts as able to follow the fleet's orders."""
        return self.automatic and not self.fatal and not self.estop


def read_state(
    state: dict[str, Any], frame: Frame, margin_m: float, within: tuple[int, int] | None = None
) -> VehicleView:
    """The fleet's view of a (schema-valid) VDA 5050 `state` on `frame`'s map (of a grid
    `within` = (width, height) squares, when given)."""
    position = state.get("agvPosition")
    under: frozenset[Cell] = frozenset()
    if (
        position is not None
        and position["positionInitialized"]
        and position["mapId"] == frame.map_id
    ):
        doubt = abs(float(position.get("deviationRange", 0.0)))
        under = frame.squares_under(position["x"], position["y"], margin_m + doubt, within)

    def described(error: dict[str, Any]) -> str:
        text = error.get("errorDescription")
        return f"{error['errorType']}: {text}" if text else str(error["errorType"])

    errors = state["errors"]
    actions = state["actionStates"]
    return VehicleView(
        under=under,
        driving=bool(state["driving"]),
        paused=bool(state.get("paused", False)),
        automatic=state["operatingMode"] == "AUTOMATIC",
        estop=state["safetyState"]["eStop"] != "NONE",
        fatal=tuple(described(e) for e in errors if e["errorLevel"] == "FATAL"),
        warnings=tuple(described(e) for e in errors if e["errorLevel"] == "WARNING"),
        battery_pct=float(state["batteryState"]["batteryCharge"]),
        charging=bool(state["batteryState"].get("charging", False)),
        errors=tuple(f"{e['errorLevel']} {described(e)}" for e in errors),
        last_node=(state["lastNodeId"], state["lastNodeSequenceId"]),
        finished=frozenset(a["actionId"] for a in actions if a["actionStatus"] == "FINISHED"),
        failed=frozenset(a["actionId"] for a in actions if a["actionStatus"] == "FAILED"),
        running=frozenset(
            a["actionId"] for a in actions if a["actionStatus"] in ("INITIALIZING", "RUNNING")
        ),
        listed=frozenset(a["actionId"] for a in actions),
    )
