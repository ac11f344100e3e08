"""Operators' goals and controls have one owner: everything else reads them, read-only."""

from __future__ import annotations

import pytest

from gridfleet.coordinator.directives import Directives
from gridfleet.grid import Cell


def test_goals_and_controls_change_only_through_their_owner() -> None:
    d = Directives({"unit2": "out_of_service"})
    d.set_goal("unit1", Cell(3, 2))
    d.set_control("unit3", "paused")
    assert dict(d.goals) == {"unit1": (3, 2)}
    assert dict(d.controls) == {"unit2": "out_of_service", "unit3": "paused"}
    with pytest.raises(TypeError):
        d.goals["unit4"] = Cell(0, 0)  # type: ignore[index]
    with pytest.raises(TypeError):
        d.controls["unit4"] = "paused"  # type: ignore[index]


def test_a_goal_is_forgotten_once_its_unit_stands_on_it_and_a_control_once_lifted() -> None:
    d = Directives()
    d.set_goal("unit1", Cell(3, 2))
    d.set_goal("unit2", Cell(1, 1))
    d.goals_reached({"unit1": Cell(3, 2), "unit2": Cell(1, 2), "unit3": None})
    assert dict(d.goals) == {"unit2": (1, 1)}
    d.set_goal("unit2", None)
    d.set_control("unit1", "paused")
    d.set_control("unit1", None)
    assert dict(d.goals) == {} and dict(d.controls) == {}
