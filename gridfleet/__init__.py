"""gridfleet: a connected robot-fleet system for grid playfields over MQTT."""

__version__ = "0.1.0"
PROTOCOL_VERSION = "1.0"
