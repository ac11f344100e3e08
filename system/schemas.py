"""Generated protocol files: the JSON Schema of every JSON message, and the protocol table.

`make schemas` (`python -m gridfleet.system.schemas [ROOT]`) writes, under the repository (or
ROOT):

- `protocol/schemas/<Model>.json`: one JSON Schema per message model used on a topic;
- `protocol/protocol.json`, `dashboard/static/js/protocol_table.js` and
  `firmware/esp32_unit/src/protocol_table.h`: the topic table and constants (see
  system/protocol_table.py).

A test fails when a committed file differs from a fresh generation.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from gridfleet.protocol import messages
from gridfleet.protocol.topics import TOPICS
from gridfleet.system import protocol_table as table

REPO = Path(__file__).resolve().parents[1]  # the checkout (this is system/schemas.py)
SCHEMA_DIR = REPO / "protocol" / "schemas"


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


def generated() -> dict[str, str]:
    """Text of every generated file, keyed by its path relative to the repository."""
    schema_dir = SCHEMA_DIR.relative_to(REPO).as_posix()
    out = {f"{schema_dir}/{name}.json": render(schema) for name, schema in schemas().items()}
    out.update(table.generated())
    return out


def write(root: Path = REPO) -> list[Path]:
    """Write every generated file under `root`; returns the paths written."""
    written = []
    for relative, text in generated().items():
        path = root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        written.append(path)
    return written


if __name__ == "__main__":
    for p in write(Path(sys.argv[1]) if len(sys.argv) > 1 else REPO):
        print(p)
