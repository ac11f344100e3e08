"""The alerts core takes every JSON message it reads exactly as its schema allows (pure).

The alerts process follows the units' connections and states, the queue view, the coordinator's
status, acknowledgements and the last run's retained alerts view (alerts/core.py). Payloads are
drawn from each kind's JSON Schema (support/schema_inputs.py): valid messages, and those with one
thing changed or no JSON object at all, told apart by jsonschema's Draft 2020-12 validator. A
valid one is read, and the rules then run over it for hours of the core's time: an
acknowledgement it cannot take (an unknown alert, an account that may not) is refused in words,
never for its shape. An invalid one is refused on `errors` with its reason and changes nothing.
None raises.
"""

from __future__ import annotations

import copy
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_alerts_core import ACCOUNTS, WATCHING_COORDINATOR, Rig, T

from gridfleet.alerts.core import AlertsCore, Effects
from gridfleet.protocol import TOPICS as SPECS
from gridfleet.protocol import ErrorReport, decode
from gridfleet.protocol import messages as models

from support.schema_inputs import allowed, edge_examples, edge_settings, parsed, payloads

READ = {
    "connection": lambda unit: T.unit("connection", unit),
    "state": lambda unit: T.unit("state", unit),
    "jobs": lambda _: T.fleet("jobs"),
    "coordinator": lambda _: T.fleet("coordinator"),
    "ack_alert": lambda _: T.request("ack_alert"),
    "alerts": lambda _: T.fleet("alerts"),
    "energy": lambda _: T.fleet("energy"),
}
# Acknowledgements by accounts that may, may not, and by nobody's client; of the alert in force
# (the stop's, n1-1), and of none.
NARROW: dict[str, dict[tuple[str, ...], Any]] = {
    "ack_alert": {
        ("$defs", "Header", "properties", "sender"): {
            "enum": ["operator", "operator-cli-1", "dashboard-7", "ann", "stranger"]
        },
        ("properties", "alert_id"): {"enum": ["n1-1", "n1-2", "nope"]},
    },
}
SETTINGS = edge_settings(70)


def rig(kind: str) -> Rig:
    """A core with a coordinator online, a unit heard, and the stop's alert in force (n1-1).

    For the alerts view, a core that has not read the last run's view yet: it takes this one.
    """
    r = Rig(WATCHING_COORDINATOR, retained=kind != "alerts", accounts=ACCOUNTS)
    r.state(1.0, "unit1", (2, 2))
    r.send(1.0, T.fleet("estop"), b"engaged|operator|drill")
    assert kind == "alerts" or [a.id for a in r.core.active.values()] == ["n1-1"]
    return r


def snapshot(core: AlertsCore) -> Any:
    """What a message may change: the alerts, what the rules know, the stop, the status."""
    kept = (
        "active",
        "cleared",
        "_units",
        "_queued",
        "_status",
        "_adopting",
        "_inheriting",
        "_energy",
    )
    return copy.deepcopy({k: getattr(core, k) for k in kept}), repr(core._stop)


def reports(effects: Effects) -> list[ErrorReport]:
    """The error reports among what the core publishes."""
    topic = T.fleet("errors")
    return [decode(ErrorReport, o.payload) for o in effects.publish if o.topic == topic]


@pytest.mark.parametrize("kind", sorted(READ))
def test_each_message_the_alerts_read_is_taken_as_its_schema_allows(kind: str) -> None:
    model = getattr(models, SPECS[kind].model or "")

    # The views are large to draw and to compare: fewer of them (8 s each at 70, half at 30).
    @settings(
        SETTINGS, max_examples=edge_examples(30 if kind in ("jobs", "alerts", "energy") else 70)
    )
    @given(
        payload=payloads(kind, max_coord=12, narrow=NARROW.get(kind)),
        unit=st.sampled_from(["unit1", "unit2"]),
    )
    def run(payload: bytes, unit: str) -> None:
        r = rig(kind)
        topic = READ[kind](unit)
        valid = allowed(kind, parsed(payload))
        before = snapshot(r.core)
        said = reports(r.send(2.0, topic, payload))
        for report in said:
            assert report.topic == topic and report.reason and "\n" not in report.reason, report
        if not valid and not payload and kind in ("connection", "state"):
            assert not said  # a retained message cleared: a unit removed, no message (§6.11)
            return
        if not valid and not payload and kind == "energy":
            # The retained view cleared (`gridfleet clean`): no view, so no battery rules.
            assert not said and r.core._energy is None
            return
        if not valid:
            assert snapshot(r.core) == before, payload
            assert len(said) == 1 and said[0].reason.startswith(f"{model.__name__}: "), said
            return
        decode(model, payload, SPECS[kind].max_bytes)  # the schema allows it: so does the code
        assert not any(r.reason.startswith(f"{model.__name__}: field ") for r in said), said
        for s in (30.0, 700.0, 7200.0):  # the rules over what it said, and the view after them
            r.tick(s)
        r.core.view()

    run()
