"""Numbers and words of the protocol that every component must agree on (see protocol.md).

This module is the one place they are written down: the message models and topic table use
them, and `make schemas` copies them into protocol/protocol.json, the dashboard's
protocol_table.js and the firmware's protocol_table.h.
"""

PROTOCOL_VERSION = "1.6"  # header.version of every JSON message (protocol.md §3, §9)
TOPIC_VERSION = "v1"  # the topic level after the root; changes only with a new major version
# Every subscription, whatever QoS its topic is published at (protocol.md §2): each gridfleet
# client is a clean session, which ends with its connection, so QoS 1 from the broker adds no
# delivery; and on RabbitMQ 3.10 it is a durable queue that pins the client to its node.
SUBSCRIBE_QOS = 0
DEFAULT_ROOT = "gridfleet"

MAX_ID_CHARS = 64
ID_PUNCTUATION = "_.-"  # allowed in ids besides ASCII letters and digits, never first
ID_PATTERN = rf"^[A-Za-z0-9][A-Za-z0-9{ID_PUNCTUATION}]{{0,{MAX_ID_CHARS - 1}}}$"
ROOT_SEGMENT_PATTERN = rf"^[A-Za-z0-9{ID_PUNCTUATION}]{{1,{MAX_ID_CHARS}}}$"
MAX_COORD = 4095  # largest x or y a message may carry; the map bounds are checked at the edge

MAX_REQUEST_BYTES = 16 * 1024  # requests, orders, goals, unit messages
MAX_VIEW_BYTES = 8 * 1024 * 1024  # retained fleet views: map, jobs, routes
# Jobs not yet final that the coordinator holds: the queue view lists each (under 1 KB even with
# 64-character ids and a 500-character wait reason), so it stays well inside MAX_VIEW_BYTES.
MAX_OPEN_JOBS = 5000
# One account's share of them: one script cannot fill the queue and shut every other account out.
MAX_OPEN_JOBS_PER_ACCOUNT = 2500
MAX_RELEASED = 64  # squares one order may release
MAX_PLANNED = 8192  # squares of the planned rest shown for display
MAX_TEXT = 500  # characters of a reason or error message
MAX_CHARGERS = 1024  # chargers one map may have
MAX_PLACES = 4096  # named places one map may have (protocol.md §5.10)
MAX_ZONES = 256  # zones closed at once (protocol.md §5.11)
# A factsheet's energy rates a second at most (a run 1,000 times faster than life).
MAX_PCT_PER_S = 100_000.0
MAX_ENERGY_UNITS = 20000  # units the energy view may list (each a few dozen bytes)

# The plain-text device payloads (protocol.md §4.6, §5.1, §5.6).
DIRECTION_NONE = "-"  # the direction payload when no move is intended; else N, E, S or W
MAX_DIRECTION_BYTES = 8
ESTOP_ENGAGED = "engaged"
ESTOP_RELEASED = "released"
ESTOP_SEPARATOR = "|"  # <engaged|released>|<by>|<reason>
MAX_ESTOP_BYTES = 512
MAX_ESTOP_REASON = 200  # characters of the one-line reason
BUTTON_ESTOP_REASON = "button"  # the <reason> of a device's button: engaged|<device>|button
MAX_DEVICE_CONNECTION_BYTES = 16  # online, offline or broken (gridfleet.protocol.device)

DEFAULT_STEP_S = 1.0  # the course's step period
HOLD_AFTER_STEPS = 3  # a unit holds still after this many step periods without an order
STALE_AFTER_STEPS = 5  # the coordinator treats a unit as lost after this many silent periods
# A unit's retained topics the coordinator clears (an empty retained message) when an operator
# removes it (protocol.md §6.11), the connection last: its echo says the others are cleared too.
# Not its `direction`: that is its device's alone to read, and a device takes no empty one.
REMOVED_UNIT_KINDS = ("state", "factsheet", "vehicle", "connection")
# A unit whose state has not changed but for its step count sends it at least this often (steps);
# well inside STALE_AFTER_STEPS, so a quiet unit is never taken for a lost one.
STATE_HEARTBEAT_STEPS = 3
MIN_TIMEOUT_S = 0.5  # no timeout is shorter than this, whatever the step period
# An order is too late to drive (protocol §4.4 rule 7) when later than this, or than the unit's
# hold time if that is longer: a busy host delays every message by up to a second, and holding a
# whole fleet for that turns a slow fleet into a stopped one (150 units beside 3 CPU hogs and an
# open page: 726 late-order holds, and 0-1.4 steps a second with the page open, from 2-4.6).
LATE_ORDER_MIN_S = 1.5
