"""The device takes every payload it reads exactly as the protocol's table allows (pure).

The device (device/core.py) reads plain text, no JSON: its unit's direction, the stop's latch
and its own press. protocol/protocol.json states each (`direction`: a letter or `-`, at most
`max_bytes`; `estop`: `engaged|<by>|<reason>` or `released|…`, `by` an id, the reason one line
of at most `max_reason_chars`, the whole at most `max_bytes`; a press only engages, names its
device, and an empty one is a press cleared). From those facts, written as JSON Schemas of one
string, payloads are drawn (hypothesis-jsonschema) with their near misses; a valid one is shown,
an invalid one is refused on `errors` with its reason and changes nothing. None raises.
"""

from __future__ import annotations

import re
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis_jsonschema import from_schema

from gridfleet.device.core import DeviceCore
from gridfleet.protocol import ErrorReport, Topics, decode

from support.schema_inputs import TABLE, edge_settings

T = Topics("t/edges")
DEVICE = "dev1"
IDS = TABLE["ids"]["pattern"].removeprefix("^").removesuffix("$")
ESTOP = TABLE["estop"]
DIRECTION = TABLE["direction"]
STATES = f"({ESTOP['engaged']}|{ESTOP['released']})"
SEP = re.escape(ESTOP["separator"])
REASON = rf"[^\r\n\x00]{{0,{ESTOP['max_reason_chars']}}}"


def text(pattern: str) -> dict[str, Any]:
    """A JSON Schema of one string that matches `pattern` whole."""
    return {"type": "string", "pattern": f"^{pattern}$"}


# Each topic the device reads: its schema, and the most bytes the table allows on it.
SCHEMAS: dict[str, tuple[dict[str, Any], int]] = {
    "direction": ({"enum": [*DIRECTION["letters"], DIRECTION["none"]]}, DIRECTION["max_bytes"]),
    "estop": (text(f"{STATES}{SEP}{IDS}({SEP}{REASON})?"), ESTOP["max_bytes"]),
    "device_stop": (
        {"anyOf": [text(f"{ESTOP['engaged']}{SEP}{DEVICE}({SEP}{REASON})?"), {"const": ""}]},
        ESTOP["max_bytes"],
    ),
}
TOPIC = {
    "direction": T.unit("direction", "unit1"),
    "estop": T.fleet("estop"),
    "device_stop": T.device("device_stop", DEVICE),
}


def allowed(kind: str, payload: bytes) -> bool:
    """Whether the table allows `payload` on topics of `kind` (UTF-8, its size, its shape)."""
    schema, max_bytes = SCHEMAS[kind]
    try:
        value = payload.decode("utf-8")
    except UnicodeDecodeError:
        return False
    if len(payload) > max_bytes:
        return False
    options = schema.get("anyOf", [schema])
    for option in options:
        if "enum" in option and value in option["enum"]:
            return True
        if "const" in option and value == option["const"]:
            return True
        if "pattern" in option and re.fullmatch(option["pattern"][1:-1], value, re.DOTALL):
            return True
    return False


def valid(kind: str) -> st.SearchStrategy[bytes]:
    """Payloads the table allows on `kind` (the byte bound on top of the schema's shape)."""
    max_bytes = SCHEMAS[kind][1]
    encoded = from_schema(SCHEMAS[kind][0]).map(lambda s: s.encode("utf-8"))
    return encoded.filter(lambda p: len(p) <= max_bytes)


@st.composite
def near_miss(draw: st.DrawFn, kind: str) -> bytes:
    """A valid payload with a piece changed, cut or added to; or bytes of no shape at all."""
    base = draw(valid(kind))
    how = draw(st.sampled_from(["swap", "cut", "add", "bytes", "line"]))
    if how == "bytes":
        return draw(st.binary(max_size=40) | st.sampled_from([b"\xff\xfe", b"x" * 600]))
    if how == "cut" and base:
        return base[: draw(st.integers(0, len(base) - 1))]
    if how == "line":
        return base + draw(st.sampled_from([b"\n", b"\r", b"\x00", b"|" + b"r" * 600]))
    if how == "add":
        return draw(st.sampled_from([b"x", b"|", b" "])) + base
    # A state, letter or id replaced by another word.
    word = draw(st.sampled_from([b"engaged", b"released", b"maybe", b"n", b"bad/id", b"dev2"]))
    parts = base.split(b"|")
    parts[draw(st.integers(0, len(parts) - 1))] = word
    return b"|".join(parts)


def core() -> DeviceCore:
    """Device dev1 of unit1, online; showing E, the stop released by an operator."""
    device = DeviceCore(T, "unit1", DEVICE)
    device.connected()
    assert device.receive(TOPIC["direction"], b"E") == []
    assert device.receive(TOPIC["estop"], b"released|operator|drill over") == []
    return device


def shown(device: DeviceCore) -> Any:
    """Everything the device shows and keeps."""
    return device.direction, device.estop, device.pressed, device.pending_stop, device.leds


SETTINGS = edge_settings(150)


@pytest.mark.parametrize("kind", sorted(SCHEMAS))
def test_each_payload_the_device_reads_is_taken_as_the_table_allows(kind: str) -> None:
    @SETTINGS
    @given(payload=valid(kind) | near_miss(kind))
    def run(payload: bytes) -> None:
        device = core()
        before = shown(device)
        outs = device.receive(TOPIC[kind], payload)
        if not allowed(kind, payload):
            assert shown(device) == before, payload
            (out,) = outs
            report = decode(ErrorReport, out.payload)
            assert out.topic == T.fleet("errors") and report.topic == TOPIC[kind], report
            assert report.reason and "\n" not in report.reason, report
            return
        assert outs == [], (payload, outs)
        text = payload.decode()
        if kind == "direction":
            assert device.leds.model_dump() == {s: s == text for s in "NESW"}
        elif kind == "estop":
            assert device.estop is not None and device.estop.engaged == text.startswith("engaged")
            assert device.estop_engaged == (device.pattern == "stop")
        else:
            assert device.pressed == bool(text) and device.pattern == (
                "stop" if text else "direction"
            )

    run()
