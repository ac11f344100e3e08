"""JSON Schemas of every JSON message, generated from the models (`python -m gridfleet.protocol.schemas`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from gridfleet.protocol import messages
from gridfleet.protocol.topics import TOPICS

SCHEMA_DIR = Path(__file__).resolve().parents[2] / "protocol" / "schemas"


def schemas() -> dict[str, dict[str, Any]]:
    """Schema of each model used on a topic, keyed by model name."""
    out: dict[str, dict[str, Any]] = {}
    for spec in TOPICS.values():
        if spec.model is None:
            continue
        model = getattr(messages, spec.model)
        schema = model.model_json_schema(mode="validation")
        schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        schema["$id"] = f"gridfleet/v1/{spec.model}.json"
        out[spec.model] = schema
    return out


def render(schema: dict[str, Any]) -> str:
    """Stable text of a schema file."""
    return json.dumps(schema, indent=2, sort_keys=True) + "\n"


def write(directory: Path = SCHEMA_DIR) -> list[Path]:
    """Write every schema file; returns the paths written."""
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name, schema in schemas().items():
        path = directory / f"{name}.json"
        path.write_text(render(schema), encoding="utf-8")
        written.append(path)
    return written


if __name__ == "__main__":
    for p in write(Path(sys.argv[1]) if len(sys.argv) > 1 else SCHEMA_DIR):
        print(p)
