"""What the page needs to know (broker, topic root, map): built and checked without any I/O."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gridfleet.config import parse_broker_url
from gridfleet.errors import ConfigError
from gridfleet.grid import GridMap
from gridfleet.protocol import Topics, validate_id
from gridfleet.protocol.constants import DEFAULT_ROOT

PACKAGE_DIR = Path(__file__).resolve().parent
MQTT_BUNDLE = Path("mqtt") / "dist" / "mqtt.esm.js"
INSTALL_HINT = (
    "MQTT.js is not installed: run 'npm ci' in the dashboard/ folder "
    "(or 'make install' at the top of the repository), then reload the page."
)


@dataclass(frozen=True)
class DashboardSettings:
    """Where the page finds the broker, which fleet it shows, and an optional starting map."""

    broker_ws: str = "ws://127.0.0.1:9001"
    root: str = DEFAULT_ROOT
    client_prefix: str = "dashboard"
    map: GridMap | None = None
    colors: dict[str, str] = field(default_factory=dict)
    node_modules: Path = PACKAGE_DIR / "node_modules"

    def __post_init__(self) -> None:
        url = parse_broker_url(self.broker_ws)
        if url.scheme != "ws":
            raise ConfigError(
                f"dashboard broker URL {self.broker_ws!r}: the page needs a websocket URL, ws://host:port"
            )
        Topics(self.root)  # raises ProtocolError naming a bad root
        validate_id(self.client_prefix, "client id prefix")

    @property
    def mqtt_bundle(self) -> Path:
        """Path of the MQTT.js browser bundle inside node_modules."""
        return self.node_modules / MQTT_BUNDLE


def settings_payload(settings: DashboardSettings, bundle_present: bool) -> dict[str, Any]:
    """The JSON body of /api/settings."""
    grid = settings.map
    return {
        "broker_ws": settings.broker_ws,
        "root": settings.root,
        "prefix": Topics(settings.root).prefix,
        "client_prefix": settings.client_prefix,
        "map": None
        if grid is None
        else {
            "name": grid.name,
            "width": grid.width,
            "height": grid.height,
            "rows": grid.rows(),
            "obstacles": [],
        },
        "colors": dict(settings.colors),
        "mqtt_js": {"available": bundle_present, "hint": None if bundle_present else INSTALL_HINT},
    }
