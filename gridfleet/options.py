"""Command-line flags every component shares: where the broker is and which topic root to use."""

from __future__ import annotations

import argparse

from gridfleet.config import DEFAULT_MQTT_URL
from gridfleet.protocol.constants import DEFAULT_ROOT


def add_common(
    parser: argparse.ArgumentParser, *, broker: bool = True, own_broker: str | None = None
) -> None:
    """Flags that most components share: --broker and --root.

    `own_broker` says what a command that starts its own broker does without --broker (the
    default is then None).
    """
    if broker:
        parser.add_argument(
            "--broker",
            default=None if own_broker else DEFAULT_MQTT_URL,
            metavar="URL",
            help=f"MQTT broker URL, mqtt://host:port (default {own_broker or DEFAULT_MQTT_URL})",
        )
    parser.add_argument(
        "--root",
        default=DEFAULT_ROOT,
        help=f"topic root, so fleets can share a broker (default {DEFAULT_ROOT!r})",
    )
