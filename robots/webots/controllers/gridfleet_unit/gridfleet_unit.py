"""Webots controller of a gridfleet grid unit (the `GridUnit` PROTO): it joins the fleet.

Webots runs this file (its name must be its folder's) once per grid unit, with the Python set in
Webots' preferences. The unit's id is the robot's name; its capacity, colour, step period, map,
broker and topic root are the GridUnit's fields (robots/webots/README.md).
"""

from __future__ import annotations

import importlib.util
import sys


def missing_gridfleet() -> str | None:
    """Why this Python cannot run the unit (None: gridfleet is installed in it)."""
    if importlib.util.find_spec("gridfleet") is not None:
        try:
            if importlib.util.find_spec("gridfleet.robots") is not None:
                return None
        except ImportError:
            pass
    return (
        f"gridfleet_unit: error: gridfleet is not installed in the Python Webots runs "
        f"({sys.executable}); set Webots' Python command to gridfleet's virtual environment "
        "(robots/webots/README.md)"
    )


def main() -> int:
    """Run the unit until Webots ends the controller."""
    missing = missing_gridfleet()
    if missing is not None:
        print(missing, file=sys.stderr)
        return 2
    try:
        from controller import Supervisor  # Webots' own module: it exists only inside Webots
    except ImportError:
        print(
            "gridfleet_unit: error: no Webots controller module; Webots runs this controller "
            "(robots/webots/README.md)",
            file=sys.stderr,
        )
        return 2
    from gridfleet.robots.webots.main import run_controller

    return run_controller(Supervisor())


if __name__ == "__main__":
    sys.exit(main())
