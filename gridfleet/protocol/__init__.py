"""The gridfleet protocol: topic names, message models, codecs and device payloads.

protocol.md is the human contract; this package is the same contract as code, and
protocol/schemas/ the same again as JSON Schema. `make schemas` also writes the topic table and
constants for other languages (protocol/protocol.json, the dashboard's protocol_table.js, the
firmware's protocol_table.h; see system/protocol_table.py). Tests keep them all in step.
"""

from gridfleet.protocol.codec import HeaderStamper, decode, encode
from gridfleet.protocol.constants import PROTOCOL_VERSION
from gridfleet.protocol.device import (
    DeviceConnection,
    EstopSignal,
    decode_device_connection,
    decode_direction,
    decode_estop,
    decode_press,
    encode_device_connection,
    encode_direction,
    encode_estop,
)
from gridfleet.protocol.messages import (
    Action,
    CancelJob,
    ClearObstacles,
    Connection,
    ControlUnit,
    CoordinatorStatus,
    ErrorReport,
    EventEntry,
    EventsView,
    Factsheet,
    FleetMap,
    Goal,
    Header,
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
    UnitState,
    VehicleCondition,
)
from gridfleet.protocol.stop import StopView
from gridfleet.protocol.topics import TOPICS, Topics, TopicSpec, validate_id

__all__ = [
    "PROTOCOL_VERSION",
    "TOPICS",
    "Action",
    "CancelJob",
    "ClearObstacles",
    "Connection",
    "ControlUnit",
    "CoordinatorStatus",
    "DeviceConnection",
    "ErrorReport",
    "EstopSignal",
    "EventEntry",
    "EventsView",
    "Factsheet",
    "FleetMap",
    "Goal",
    "Header",
    "HeaderStamper",
    "JobView",
    "JobsView",
    "Leds",
    "Order",
    "Reply",
    "RouteView",
    "Routes",
    "Sensors",
    "SetGoal",
    "StopView",
    "SubmitJob",
    "TopicSpec",
    "Topics",
    "UnitState",
    "VehicleCondition",
    "decode",
    "decode_device_connection",
    "decode_direction",
    "decode_estop",
    "decode_press",
    "encode",
    "encode_device_connection",
    "encode_direction",
    "encode_estop",
    "validate_id",
]
