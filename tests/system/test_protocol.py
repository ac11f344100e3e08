"""Protocol module: every message round-trips; every kind of bad payload is refused by name."""

from __future__ import annotations

import json
import re
from datetime import UTC, datetime
from typing import Any, get_args

import pytest

from gridfleet.errors import ProtocolError
from gridfleet.grid import Cell, Direction
from gridfleet.protocol import (
    TOPICS,
    Action,
    CancelJob,
    Connection,
    CoordinatorStatus,
    ErrorReport,
    EstopSignal,
    Factsheet,
    FleetMap,
    Goal,
    Header,
    HeaderStamper,
    JobsView,
    JobView,
    Leds,
    Order,
    Reply,
    Routes,
    RouteView,
    Sensors,
    SetGoal,
    SubmitJob,
    Topics,
    UnitState,
    decode,
    decode_device_connection,
    decode_direction,
    decode_estop,
    encode,
    encode_device_connection,
    encode_direction,
    encode_estop,
)
from gridfleet.protocol.constants import (
    DIRECTION_NONE,
    ESTOP_ENGAGED,
    ESTOP_RELEASED,
    ESTOP_SEPARATOR,
    ID_PATTERN,
    MAX_ESTOP_REASON,
    PROTOCOL_VERSION,
    TOPIC_VERSION,
)
from gridfleet.protocol.device import DEVICE_STATES, DEVICE_WILL
from gridfleet.protocol.messages import FINAL_JOB_STATES, DirectionLetter, Message

from support.paths import REPO
from support.scripts import gen_protocol

TABLE_FILE = REPO / gen_protocol.TABLE_PATH
protocol_table = gen_protocol.protocol_table

FIXED = datetime(2026, 11, 21, 10, 0, tzinfo=UTC)
stamp = HeaderStamper("unit1", clock=lambda: FIXED)
SENSORS = Sensors(N="free", E="wall", S="obstacle", W="unit")


def samples() -> list[Message]:
    job = JobView(id="job-1", pickup=Cell(1, 1), dropoff=Cell(2, 2), mass_kg=1.0, state="queued")
    return [
        Connection(header=stamp("connection"), state="online"),
        Factsheet(header=stamp("factsheet"), capacity_kg=5.0, step_period_s=0.5),
        UnitState(
            header=stamp("state"),
            step=3,
            position=Cell(1, 2),
            direction="N",
            status="moving",
            leds=Leds(N=True),
            sensors=SENSORS,
            obstacles=[Cell(2, 2)],
            released=[Cell(1, 1)],
        ),
        Order(
            header=stamp("order"),
            order_id="o-1",
            update_id=1,
            released=[Cell(1, 1)],
            planned=[Cell(1, 0)],
            target=Cell(1, 0),
            action=Action(kind="pick", job_id="job-1", square=Cell(1, 0), mass_kg=1.0),
        ),
        Goal(header=stamp("goal"), target=None),
        FleetMap(header=stamp("map"), name="m", width=2, height=1, rows=[".@"]),
        JobsView(header=stamp("jobs"), jobs=[job], counts={"queued": 1}),
        Routes(header=stamp("routes"), step=1, routes={"unit1": RouteView(released=[Cell(0, 0)])}),
        SubmitJob(
            header=stamp("submit_job"),
            request_id="r",
            reply_to="dash",
            pickup=Cell(0, 0),
            dropoff=Cell(1, 0),
            mass_kg=2.5,
        ),
        CancelJob(header=stamp("cancel_job"), request_id="r", job_id="job-1"),
        SetGoal(header=stamp("set_goal"), request_id="r", unit="unit1", target=Cell(3, 3)),
        Reply(header=stamp("reply"), request_id="r", accepted=False, reason="no"),
        ErrorReport(header=stamp("errors"), topic="x", reason="bad"),
        CoordinatorStatus(header=stamp("coordinator"), state="online", step=4, estop=True),
    ]


@pytest.mark.parametrize("message", samples(), ids=lambda m: type(m).__name__)
def test_every_message_round_trips(message: Message) -> None:
    assert decode(type(message), encode(message)) == message


def test_squares_decode_to_cells() -> None:
    order = decode(Order, encode(samples()[3]))
    assert order.released == [Cell(1, 1)] and isinstance(order.released[0], Cell)
    assert order.target == Cell(1, 0)


def test_header_counts_per_topic_kind_and_names_the_sender() -> None:
    s = HeaderStamper("coord", clock=lambda: FIXED)
    assert [s("order").seq, s("order").seq, s("jobs").seq] == [0, 1, 0]
    assert s("order").sender == "coord"
    with pytest.raises(ProtocolError, match="sender"):
        HeaderStamper("bad/id")


def _order(**changes: Any) -> bytes:
    data = json.loads(encode(samples()[3]))
    data.update(changes)
    return json.dumps(data).encode()


@pytest.mark.parametrize(
    ("payload", "named"),
    [
        (b"{not json", "malformed JSON"),
        (b"[1, 2]", "Input should be an object"),
        (b"", "malformed JSON"),
        (_order(update_id="5"), "update_id"),
        (_order(update_id=0), "update_id"),
        (_order(released=[[1, -1]]), "released.0.1"),
        (_order(released=[[1, 2, 3]]), "released.0"),
        (_order(released=[[1.5, 2]]), "released.0.0"),
        (_order(released=[[5000, 2]]), "released.0.0"),
        (_order(released=[[1, 1]] * 65), "released"),
        (_order(order_id=""), "order_id"),
        (_order(surprise=1), "surprise"),
        (
            _order(action={"kind": "throw", "job_id": "j", "square": [0, 0], "mass_kg": 1}),
            "action.kind",
        ),
        (
            _order(action={"kind": "pick", "job_id": "j", "square": [0, 0], "mass_kg": 0}),
            "action.mass_kg",
        ),
        (
            _order(
                header={
                    "version": "9.9",
                    "seq": 0,
                    "timestamp": "2026-01-01T00:00:00Z",
                    "sender": "x",
                }
            ),
            "header.version",
        ),
        (
            _order(
                header={
                    "version": "1.6",
                    "seq": 0,
                    "timestamp": "2026-01-01T00:00:00Z",
                    "sender": "a/b",
                }
            ),
            "header.sender",
        ),
        (
            _order(header={"version": "1.6", "seq": 0, "timestamp": "yesterday", "sender": "x"}),
            "header.timestamp",
        ),
    ],
)
def test_bad_orders_are_refused_naming_the_field(payload: bytes, named: str) -> None:
    with pytest.raises(ProtocolError, match="Order") as info:
        decode(Order, payload)
    assert named in str(info.value)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("mass_kg", 0),
        ("mass_kg", -1),
        ("mass_kg", "heavy"),
        ("mass_kg", "1.5"),  # a number in a string is no number on the wire
        ("mass_kg", float("nan")),
        ("priority", "1"),
        ("priority", 1.5),
        ("priority", True),
        ("pickup", ["1", 2]),
        ("pickup", None),
        ("priority", 101),
        ("job_id", "a/b"),
        ("reply_to", "#"),
    ],
)
def test_bad_job_requests_are_refused_naming_the_field(field: str, value: Any) -> None:
    data = json.loads(encode(samples()[8]))
    data[field] = value
    with pytest.raises(ProtocolError, match=field):
        decode(SubmitJob, json.dumps(data).encode())


def test_whole_numbers_written_with_a_fraction_are_integers_as_json_schema_says() -> None:
    # JSON has one kind of number: 3.0 is the integer 3 (JSON Schema's "integer" takes it).
    data = json.loads(encode(samples()[8]))
    data |= {"priority": 7.0, "pickup": [1.0, 2e0]}
    data["header"]["seq"] = 3.0
    job = decode(SubmitJob, json.dumps(data).encode())
    assert (job.priority, job.pickup, job.header.seq) == (7, Cell(1, 2), 3)
    assert type(job.priority) is int and type(job.mass_kg) is float
    data["priority"] = 7.5  # still no integer, and named as before
    with pytest.raises(ProtocolError, match="priority"):
        decode(SubmitJob, json.dumps(data).encode())


def test_oversized_payloads_are_refused_before_parsing() -> None:
    with pytest.raises(ProtocolError, match="exceeds the limit"):
        decode(SubmitJob, b"{" + b" " * 20000 + b"}")


def test_bad_unit_state_fields_are_named() -> None:
    data = json.loads(encode(samples()[2]))
    data["sensors"]["N"] = "dragon"
    with pytest.raises(ProtocolError, match=r"sensors\.N"):
        decode(UnitState, json.dumps(data))
    data = json.loads(encode(samples()[2]))
    data["status"] = "dancing"
    with pytest.raises(ProtocolError, match="status"):
        decode(UnitState, json.dumps(data))


@pytest.mark.parametrize("direction", [*Direction, None])
def test_direction_payload_round_trips(direction: Direction | None) -> None:
    assert decode_direction(encode_direction(direction)) == direction


@pytest.mark.parametrize("payload", [b"", b"NE", b"x", b"\xff", b"n"])
def test_bad_direction_payload_is_refused(payload: bytes) -> None:
    with pytest.raises(ProtocolError, match="direction"):
        decode_direction(payload)


def test_estop_payload_round_trips() -> None:
    for signal in (EstopSignal(True, "dashboard", "pressed | twice"), EstopSignal(False, "op")):
        assert decode_estop(encode_estop(signal)) == signal
    assert encode_estop(EstopSignal(True, "esp32-unit1", "button")) == b"engaged|esp32-unit1|button"


@pytest.mark.parametrize(
    "payload",
    [
        b"",
        b"engaged",
        b"ENGAGED|x|y",
        b"stop|x|",
        b"engaged|bad/id|x",
        b"engaged|x|" + b"r" * 300,
        b"engaged|x|two\nlines",
        b"engaged|x\n|trailing newline in the id",
        b"\xff\xfe",
        b"engaged|x|" + b"y" * 600,
    ],
)
def test_bad_estop_payload_is_refused(payload: bytes) -> None:
    with pytest.raises(ProtocolError, match="estop"):
        decode_estop(payload)


def test_topics_are_built_and_parsed() -> None:
    t = Topics("lab/a")
    assert t.unit("state", "unit1") == "lab/a/v1/units/unit1/state"
    assert t.fleet("estop") == "lab/a/v1/fleet/estop"
    assert t.request("submit_job") == "lab/a/v1/requests/submit_job"
    assert t.reply("dash") == "lab/a/v1/replies/dash"
    assert t.all_units("state") == "lab/a/v1/units/+/state"
    assert t.parse("lab/a/v1/units/unit1/order") == ("order", "unit1")
    assert t.parse("lab/a/v1/fleet/jobs") == ("jobs", None)
    assert t.parse("lab/a/v1/replies/dash") == ("reply", "dash")


@pytest.mark.parametrize(
    "call",
    [
        lambda t: t.unit("state", "a/b"),
        lambda t: t.unit("state", "+"),
        lambda t: t.unit("state", ""),
        lambda t: t.unit("state", "unit1\n"),  # `$` alone would let a trailing newline through
        lambda t: t.unit("estop", "u1"),
        lambda t: t.fleet("state"),
        lambda t: t.request("jobs"),
        lambda t: t.parse("other/v1/fleet/jobs"),
        lambda t: t.parse("gridfleet/v1/units/u1/nope"),
        lambda t: t.parse("gridfleet/v1/units/$x/state"),
    ],
)
def test_bad_topics_and_ids_are_refused(call: Any) -> None:
    with pytest.raises(ProtocolError):
        call(Topics())


@pytest.mark.parametrize("root", ["", "a//b", "a/+", "#", "$SYS", "a b", "lab\n"])
def test_bad_roots_are_refused(root: str) -> None:
    with pytest.raises(ProtocolError, match="topic root"):
        Topics(root)


def test_one_protocol_version_which_headers_carry_and_check() -> None:
    import gridfleet

    assert getattr(gridfleet, "PROTOCOL_VERSION", PROTOCOL_VERSION) is PROTOCOL_VERSION
    assert stamp("state").version == PROTOCOL_VERSION
    schema = Header.model_json_schema()["properties"]["version"]
    assert schema["const"] == schema["default"] == PROTOCOL_VERSION
    data = json.loads(encode(samples()[3]))
    data["header"]["version"] = PROTOCOL_VERSION + ".1"
    with pytest.raises(ProtocolError, match=r"header\.version.*" + re.escape(PROTOCOL_VERSION)):
        decode(Order, json.dumps(data))


def test_device_payload_words_are_the_constants() -> None:
    assert ID_PATTERN == r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"  # as protocol.md §1 writes it
    assert encode_direction(None).decode() == DIRECTION_NONE
    assert [d.value for d in Direction] + [DIRECTION_NONE] == list(get_args(DirectionLetter))
    engaged = encode_estop(EstopSignal(True, "op", "why")).decode()
    assert engaged.split(ESTOP_SEPARATOR) == [ESTOP_ENGAGED, "op", "why"]
    assert encode_estop(EstopSignal(False, "op")).decode().startswith(ESTOP_RELEASED)
    assert decode_estop(ESTOP_RELEASED + ESTOP_SEPARATOR + "op").engaged is False
    with pytest.raises(ProtocolError, match="200"):
        EstopSignal(True, "op", "r" * (MAX_ESTOP_REASON + 1))
    assert DEVICE_WILL in DEVICE_STATES
    assert {decode_device_connection(encode_device_connection(s)) for s in DEVICE_STATES} == set(
        DEVICE_STATES
    )


def test_the_generated_table_is_read_from_the_code() -> None:
    t = protocol_table()
    assert json.loads(TABLE_FILE.read_text())["protocol_version"] == PROTOCOL_VERSION
    assert (t["protocol_version"], t["topic_version"]) == (PROTOCOL_VERSION, TOPIC_VERSION)
    assert t["ids"]["pattern"] == ID_PATTERN
    assert set(t["topics"]) == set(TOPICS)
    topics = Topics("r")
    for kind, row in t["topics"].items():
        spec = TOPICS[kind]
        assert (row["qos"], row["retained"], row["max_bytes"]) == (
            spec.qos,
            spec.retained,
            spec.max_bytes,
        )
        path = row["pattern"].replace("{" + str(row["placeholder"]) + "}", "x1")
        assert topics.parse(f"r/{TOPIC_VERSION}/{path}")[0] == kind
    assert [*t["direction"]["letters"], t["direction"]["none"]] == list(get_args(DirectionLetter))
    assert set(t["final_job_states"]) == FINAL_JOB_STATES
    assert t["device_connection"]["states"] == list(DEVICE_STATES)
    text = ESTOP_SEPARATOR.join([t["estop"]["engaged"], "op", "r" * t["estop"]["max_reason_chars"]])
    assert decode_estop(text.encode()).engaged
