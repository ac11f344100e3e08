"""VDA 5050 instant actions the fleet sends a vehicle: pause, resume, cancel, factsheet request,
state request, start and stop charging.

The fleet's emergency stop (any source), and an operator's pause or out-of-service of the unit,
pause the vehicle (`startPause`) until the release (`stopPause`); a cancelled job cancels the
order (`cancelOrder`). A vehicle heard on line before any state of its is asked for one
(`stateRequest`: it may otherwise stay silent for 30 s). A unit whose order says `charge` and that stands
there with nothing left to drive is told `startCharging`; an order taking it elsewhere is held
back until `stopCharging` has ended the charge (charging.py). `factsheetRequest` exists from 2.1 on; a 2.0 vehicle's capacity and speed
are configured by hand.

vda-5050-lib 1.4.0 in 2.0 mode reads the actions under 1.1's key `instantActions` instead of the
spec's `actions`. The schemas allow other keys beside the required ones, so a vehicle configured
with `legacy_actions_key` gets the same list under both keys: still valid, and read either way.
Likewise the official 2.0.0 JSON schema of `instantActions` requires `actionName` where the
specification's text (and 2.1) say `actionType`: a 2.0 action carries both.
"""

from __future__ import annotations

from typing import Any, Literal

from gridfleet.errors import ConfigError
from gridfleet.robots.vda5050.wire import Headers

InstantKind = Literal[
    "startPause",
    "stopPause",
    "cancelOrder",
    "factsheetRequest",
    "stateRequest",
    "startCharging",
    "stopCharging",
]


def instant_action(
    headers: Headers,
    kind: InstantKind,
    action_id: str,
    now: float,
    *,
    legacy_actions_key: bool = False,
) -> dict[str, Any]:
    """The `instantActions` message with one action of `kind` (blocking: HARD)."""
    if kind == "factsheetRequest" and headers.vehicle.version == "2.0.0":
        raise ConfigError(f"vehicle {headers.vehicle.unit}: VDA 5050 2.0.0 has no factsheetRequest")
    action: dict[str, Any] = {"actionId": action_id, "actionType": kind, "blockingType": "HARD"}
    if headers.vehicle.version == "2.0.0":
        action["actionName"] = kind  # what 2.0.0's schema requires; the spec's text says actionType
    action["actionParameters"] = []
    actions = [action]
    message: dict[str, Any] = {**headers("instantActions", now), "actions": actions}
    if legacy_actions_key:
        message["instantActions"] = actions
    return message
