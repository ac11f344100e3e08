"""VDA 5050's topics and headers for one vehicle (VDA 5050 2.0.0 and 2.1.0, §6.x of the spec).

Topics are `<interfaceName>/<majorVersion>/<manufacturer>/<serialNumber>/<topic>`, the major
version written `v2`. Every message starts with a header whose `headerId` counts the messages
sent on that topic, and whose `timestamp` is ISO 8601 in UTC.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, Literal

from gridfleet.errors import ConfigError
from gridfleet.protocol import validate_id

Version = Literal["2.0.0", "2.1.0"]
VERSIONS: tuple[Version, ...] = ("2.0.0", "2.1.0")
VdaTopic = Literal["order", "instantActions", "state", "visualization", "connection", "factsheet"]


@dataclass(frozen=True)
class Vehicle:
    """One VDA 5050 vehicle: who it is on the wire, and the gridfleet unit it is."""

    unit: str
    manufacturer: str
    serial_number: str
    version: Version = "2.0.0"
    interface_name: str = "uagv"

    def __post_init__(self) -> None:
        validate_id(self.unit, "unit")
        for name in ("manufacturer", "serial_number", "interface_name"):
            value = getattr(self, name)
            # Each is one topic level: MQTT's separators and wildcards would change the topic.
            if not value or any(c in value for c in "/+#") or value.startswith("$"):
                raise ConfigError(f"vehicle {self.unit}: {name} {value!r} cannot be a topic level")
        if self.version not in VERSIONS:
            raise ConfigError(
                f"vehicle {self.unit}: version {self.version!r} is not one of {VERSIONS}"
            )

    @property
    def prefix(self) -> str:
        """What its topics start with: interfaceName/majorVersion/manufacturer/serialNumber."""
        major = "v" + self.version.split(".")[0]
        return f"{self.interface_name}/{major}/{self.manufacturer}/{self.serial_number}"

    def topic(self, name: VdaTopic) -> str:
        """The vehicle's topic `name`."""
        return f"{self.prefix}/{name}"


def timestamp(now: float) -> str:
    """`now` (seconds since the epoch) as VDA 5050 writes it: ISO 8601, UTC, milliseconds."""
    return (
        datetime.fromtimestamp(now, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")
    )


@dataclass
class Headers:
    """The headers of what the master control sends one vehicle: a count per topic."""

    vehicle: Vehicle
    _sent: dict[str, int] = field(default_factory=dict)

    def __call__(self, topic: VdaTopic, now: float) -> dict[str, Any]:
        """The next header on `topic`."""
        header_id = self._sent.get(topic, -1) + 1
        self._sent[topic] = header_id
        return {
            "headerId": header_id,
            "timestamp": timestamp(now),
            "version": self.vehicle.version,
            "manufacturer": self.vehicle.manufacturer,
            "serialNumber": self.vehicle.serial_number,
        }
