"""Numbers of the protocol that every component must agree on (see protocol.md, "Timing")."""

PROTOCOL_VERSION = "1.0"
TOPIC_VERSION = "v1"
DEFAULT_ROOT = "gridfleet"

ID_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
MAX_COORD = 4095  # largest x or y a message may carry; the map bounds are checked at the edge

MAX_REQUEST_BYTES = 16 * 1024  # requests, orders, goals, unit messages
MAX_VIEW_BYTES = 8 * 1024 * 1024  # retained fleet views: map, jobs, routes
MAX_RELEASED = 64  # squares one order may release
MAX_PLANNED = 8192  # squares of the planned rest shown for display
MAX_TEXT = 500  # characters of a reason or error message

DEFAULT_STEP_S = 1.0  # the course's step period
HOLD_AFTER_STEPS = 3  # a unit holds still after this many step periods without an order
STALE_AFTER_STEPS = 5  # the coordinator treats a unit as lost after this many silent periods
MIN_TIMEOUT_S = 0.5  # no timeout is shorter than this, whatever the step period
