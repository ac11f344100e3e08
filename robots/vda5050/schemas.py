"""The official VDA 5050 JSON schemas, when a copy is at hand: every message held to its version's.

gridfleet ships no copy (they are VDA's files): point `--schemas` at a folder holding `2.0.0/` and
`2.1.0/` as VDA publishes them (`<topic>.schema.json` each). Without one, what the adapter sends
is built to the schemas (the tests hold it to them) and what it receives is checked field by
field (inbound.py).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator

from gridfleet.errors import ConfigError, ProtocolError
from gridfleet.robots.vda5050.wire import VERSIONS, VdaTopic, Version

TOPICS: tuple[VdaTopic, ...] = (
    "order",
    "instantActions",
    "state",
    "visualization",
    "connection",
    "factsheet",
)


class Schemas:
    """The validators of one folder of official schemas, by version and topic."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._validators: dict[tuple[str, str], Draft202012Validator] = {}
        for version in VERSIONS:
            for topic in TOPICS:
                path = folder / version / f"{topic}.schema.json"
                try:
                    schema = json.loads(path.read_text(encoding="utf-8"))
                except FileNotFoundError:
                    raise ConfigError(
                        f"{path}: no such schema (the folder holds 2.0.0/ and 2.1.0/ as VDA publishes them)"
                    ) from None
                except (OSError, ValueError) as exc:
                    raise ConfigError(f"{path}: cannot read the schema: {exc}") from None
                self._validators[(version, topic)] = Draft202012Validator(schema)

    def problems(self, version: Version, topic: VdaTopic | str, message: Any) -> list[str]:
        """What is wrong with `message` on `topic` of `version` (empty: valid)."""
        validator = self._validators.get((version, topic))
        if validator is None:
            return [f"{topic!r} is not a VDA 5050 topic"]
        return sorted(
            f"{'.'.join(str(p) for p in e.absolute_path) or 'message'}: {e.message}"
            for e in validator.iter_errors(message)
        )

    def check(self, version: Version, topic: VdaTopic, message: Any) -> None:
        """ProtocolError naming the first problem, if `message` is not valid."""
        found = self.problems(version, topic, message)
        if found:
            raise ProtocolError(f"{topic} ({version}) against the official schema: {found[0]}")
