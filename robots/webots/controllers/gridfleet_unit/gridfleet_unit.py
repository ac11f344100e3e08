"""Webots controller of a gridfleet grid unit (the `GridUnit` PROTO): it joins the fleet.

Webots runs this file (its name must be its folder's) once per grid unit, with the Python set in
Webots' preferences. The unit's id is the robot's name; its capacity, colour, step period, map,
broker and topic root are the GridUnit's fields (robots/webots/README.md).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

CHECKOUT = Path(__file__).resolve().parents[4]  # .../robots/webots/controllers/gridfleet_unit


def find_gridfleet(path: list[str]) -> None:
    """Put the checkout this file is in on `path` when gridfleet is not installed already."""
    if importlib.util.find_spec("robots") is None:
        path.insert(0, str(CHECKOUT))


def main() -> int:
    """Run the unit until Webots ends the controller."""
    find_gridfleet(sys.path)
    try:
        from controller import Supervisor  # Webots' own module: it exists only inside Webots
    except ImportError:
        print(
            "gridfleet_unit: error: no Webots controller module; Webots runs this controller "
            "(robots/webots/README.md)",
            file=sys.stderr,
        )
        return 2
    from robots.webots.main import run_controller

    return run_controller(Supervisor())


if __name__ == "__main__":
    sys.exit(main())
