"""VDA 5050 test material: where the official schemas are, and a valid vehicle state to vary."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from gridfleet.robots.vda5050.schemas import Schemas

# VDA's schemas are not shipped (they are VDA's files): the workplace keeps a copy beside the
# checkout; GRIDFLEET_VDA5050_SCHEMAS names another folder.
SCHEMAS = Path(
    os.environ.get(
        "GRIDFLEET_VDA5050_SCHEMAS", Path(__file__).resolve().parents[3] / "shared" / "vda5050"
    )
)
needs_schemas = pytest.mark.skipif(
    not SCHEMAS.exists(), reason=f"no official VDA 5050 schemas at {SCHEMAS}"
)


def official() -> Schemas:
    """The official schemas (tests that use them are marked `needs_schemas`)."""
    return Schemas(SCHEMAS)


def official_if_here() -> Schemas | None:
    """The official schemas when the folder is there, else None.

    The end-to-end tests run either way (what they check of the fleet needs no schema); with
    the schemas, every message of theirs is held to them as well.
    """
    return Schemas(SCHEMAS) if SCHEMAS.exists() else None


def state(version: str = "2.0.0", **changes: Any) -> dict[str, Any]:
    """A VDA 5050 state of a vehicle at the centre of square (0, 0), idle, all well."""
    base: dict[str, Any] = {
        "headerId": 7,
        "timestamp": "2026-11-26T12:00:00.000Z",
        "version": version,
        "manufacturer": "acme",
        "serialNumber": "sn-7",
        "orderId": "gf-ab12-1",
        "orderUpdateId": 0,
        "lastNodeId": "sq-0-0",
        "lastNodeSequenceId": 0,
        "nodeStates": [],
        "edgeStates": [],
        "agvPosition": {
            "x": 0.0,
            "y": 0.0,
            "theta": 0.0,
            "mapId": "hall",
            "positionInitialized": True,
        },
        "driving": False,
        "paused": False,
        "actionStates": [],
        "batteryState": {"batteryCharge": 81.5, "charging": False},
        "operatingMode": "AUTOMATIC",
        "errors": [],
        "safetyState": {"eStop": "NONE", "fieldViolation": False},
    }
    return {**base, **changes}
