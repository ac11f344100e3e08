"""A unit takes every JSON message it reads exactly as its schema allows (pure).

The unit's core (robots/core.py) reads orders (coordinated), goals (standalone) and the
coordinator's status, and other units' states when it watches its peers. Payloads are drawn from
each kind's JSON Schema (support/schema_inputs.py): valid messages, and those with one thing
changed or no JSON object at all, told apart by jsonschema's Draft 2020-12 validator. A valid one
is decoded and handled: an order or goal it cannot follow (a square off the map, a jump) is
refused in one line on `errors`, never for its shape. An invalid one is refused on `errors` with
its reason and changes nothing but the error the unit's next state reports. None raises.
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given

from gridfleet.grid import Cell, GridMap
from gridfleet.outbound import Outbound
from gridfleet.protocol import TOPICS as SPECS
from gridfleet.protocol import ErrorReport, Topics, decode
from gridfleet.protocol import messages as models
from gridfleet.robots.core import UnitCore
from gridfleet.robots.unit import Mode, UnitLogic

from support.effects import STAMP, stamper
from support.schema_inputs import allowed, edge_settings, messages, parsed, payloads

TOPICS = Topics("gf")
GRID = GridMap.from_rows(["......", "..@...", "......", "......"])
EDGE = max(GRID.width, GRID.height) + 1  # squares on the map, on its wall, and just off it
# Headers of the coordinator's clock (the unit's own, support.effects.FIXED) as well as any other.
NEAR_FIXED = {"enum": [STAMP, "2026-11-21T09:59:59.75Z", "2026-11-21T11:00:00.2+01:00"]}
ON_TIME = {("$defs", "Header", "properties", "timestamp"): NEAR_FIXED}
SETTINGS = edge_settings(80)
# The kind, the mode the unit reads it in, and the topic it comes on.
READ: dict[str, tuple[Mode, str]] = {
    "order": ("coordinated", TOPICS.unit("order", "u1")),
    "goal": ("standalone", TOPICS.unit("goal", "u1")),
    "coordinator": ("coordinated", TOPICS.fleet("coordinator")),
}


def ready(mode: Mode) -> UnitCore:
    """Unit u1 on [0, 1], connected and past its wait for the retained stop."""
    logic = UnitLogic("u1", GRID, Cell(0, 1), 5.0, 0.1, mode=mode)
    core = UnitCore(logic, TOPICS, stamp=stamper("u1"))
    core.start(0.0)
    core.on_connect(0.0)
    core.tick(lambda: dict.fromkeys(logic.sensors, "free"), lambda _: True, 0.2)
    assert core.logic.estop_known
    return core


def snapshot(core: UnitCore) -> Any:
    """What a message may change in the unit: everything it knows, less the errors it reports."""
    logic = core.logic
    return (
        {k: repr(v) for k, v in vars(logic).items() if k not in ("errors", "orders", "navigator")},
        repr(vars(logic.orders)),
        repr(logic.navigator.goal),
        core.lateness._least,
    )


def reports(outs: list[Outbound]) -> list[ErrorReport]:
    """The error reports among what the unit publishes."""
    topic = TOPICS.fleet("errors")
    return [decode(ErrorReport, o.payload) for o in outs if o.topic == topic]


@pytest.mark.parametrize("kind", sorted(READ))
def test_each_message_a_unit_reads_is_taken_as_its_schema_allows(kind: str) -> None:
    mode, topic = READ[kind]
    model = getattr(models, SPECS[kind].model or "")

    @SETTINGS
    @given(payload=payloads(kind, max_coord=EDGE, narrow=ON_TIME) | payloads(kind))
    def run(payload: bytes) -> None:
        core = ready(mode)
        valid = allowed(kind, parsed(payload))
        before = snapshot(core)
        said = reports(core.on_message(topic, payload, 0.3))
        for report in said:
            assert report.topic == topic and report.reason and "\n" not in report.reason, report
        if not valid:
            assert snapshot(core) == before, payload
            if kind == "coordinator" and not payload:  # a retained status cleared: no message
                assert not said
                return
            assert len(said) == 1 and said[0].reason.startswith(f"{model.__name__}: "), said
            return
        decode(model, payload)  # the schema allows it: the unit's own model takes it
        assert not any(r.reason.startswith(f"{model.__name__}: field ") for r in said), said

    run()


def test_an_accepted_order_is_driven_and_a_valid_one_off_the_map_is_refused_in_words() -> None:
    hdr = {"seq": 0, "timestamp": STAMP, "sender": "coordinator"}
    order = {"header": hdr, "order_id": "o", "update_id": 1, "released": [[1, 1]]}
    core = ready("coordinated")
    assert not reports(core.on_message(READ["order"][1], json.dumps(order).encode(), 0.3))
    assert core.logic.orders.released
    away = {**order, "order_id": "p", "released": [[4095, 4095]]}
    (report,) = reports(core.on_message(READ["order"][1], json.dumps(away).encode(), 0.35))
    assert "4095" in report.reason and "field" not in report.reason


@SETTINGS
@given(state=messages("state", max_coord=EDGE))
def test_a_peer_state_the_schema_allows_gives_its_position(state: dict[str, Any]) -> None:
    core = ready("standalone")
    seen = core.peer_position(TOPICS.unit("state", "u2"), json.dumps(state).encode())
    assert seen == ("u2", Cell(*state["position"]))


@SETTINGS
@given(payload=payloads("state", max_coord=EDGE))
def test_a_peer_state_the_schema_refuses_gives_nothing(payload: bytes) -> None:
    core = ready("standalone")
    seen = core.peer_position(TOPICS.unit("state", "u2"), payload)
    assert (seen is not None) == allowed("state", parsed(payload))
