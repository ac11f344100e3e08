"""What operators asked of units, with one owner: goals and controls (protocol.md §6.3, §6.4).

A goal pins a unit to a square until it stands there; a control pauses a unit or takes it out of
service until an operator lifts it. Everything else in the coordinator reads them through the
read-only views here; only the requests that set them and the progress that sees a goal reached
change them, through the methods.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from gridfleet.grid import Cell
from gridfleet.protocol.messages import UnitControlState


class Directives:
    """Each unit's goal and each unit's control, changed only through these methods."""

    def __init__(self, controls: Mapping[str, UnitControlState] | None = None) -> None:
        self._goals: dict[str, Cell] = {}
        self._controls: dict[str, UnitControlState] = dict(controls or {})
        self.goals: Mapping[str, Cell] = MappingProxyType(self._goals)  # unit -> its goal
        self.controls: Mapping[str, UnitControlState] = MappingProxyType(self._controls)

    def set_goal(self, unit: str, target: Cell | None) -> None:
        """Pin `unit` to `target`; None clears its goal."""
        if target is None:
            self._goals.pop(unit, None)
        else:
            self._goals[unit] = target

    def goals_reached(self, positions: Mapping[str, Cell | None]) -> None:
        """Forget the goal of every unit that stands on it now."""
        for unit in [u for u, goal in self._goals.items() if positions.get(u) == goal]:
            del self._goals[unit]

    def set_control(self, unit: str, control: UnitControlState | None) -> None:
        """Pause `unit` or take it out of service; None lifts what was set."""
        if control is None:
            self._controls.pop(unit, None)
        else:
            self._controls[unit] = control
