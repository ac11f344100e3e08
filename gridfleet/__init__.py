"""gridfleet: a connected robot-fleet system for grid playfields over MQTT."""

__version__ = "0.1.0"
# The protocol version is gridfleet.protocol.constants.PROTOCOL_VERSION (one definition).
