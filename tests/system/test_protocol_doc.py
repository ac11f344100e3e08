"""protocol.md, the code and the JSON Schemas say the same thing."""

from __future__ import annotations

import json
import re
from typing import Any

import jsonschema
import pytest

from gridfleet.protocol import (
    PROTOCOL_VERSION,
    TOPICS,
    decode,
    decode_device_connection,
    decode_direction,
    decode_estop,
    decode_press,
    messages,
)

from support.scripts import gen_protocol

REPO, SCHEMA_DIR = gen_protocol.REPO, gen_protocol.SCHEMA_DIR
generated, render, schemas = gen_protocol.generated, gen_protocol.render, gen_protocol.schemas
DOC = REPO / "protocol.md"
BLOCK_RE = re.compile(r"^```(json|text) (\w+)\n(.*?)^```", re.S | re.M)


def examples() -> list[tuple[str, str, str]]:
    return [(lang, kind, body) for lang, kind, body in BLOCK_RE.findall(DOC.read_text())]


def test_every_topic_kind_has_an_example() -> None:
    covered = {kind for _, kind, _ in examples()}
    assert covered == set(TOPICS), f"missing examples: {set(TOPICS) - covered}"


@pytest.mark.parametrize(
    ("lang", "kind", "body"), examples(), ids=[f"{k}-{i}" for i, (_, k, _) in enumerate(examples())]
)
def test_example_parses_with_the_code_and_validates_against_the_schema(
    lang: str, kind: str, body: str
) -> None:
    spec = TOPICS[kind]
    if spec.payload == "direction":
        decode_direction(body.strip())
        return
    if kind in ("stop", "device_stop"):  # a press: engage only, naming its source
        text = body.strip()
        press = decode_press(text, text.split("|")[1])
        assert press is not None and press.engaged
        return
    if spec.payload == "estop":
        decode_estop(body.strip())
        return
    if spec.payload == "device_connection":
        decode_device_connection(body.strip())
        return
    assert lang == "json" and spec.model is not None
    model = getattr(messages, spec.model)
    decoded = decode(model, body.encode(), spec.max_bytes)
    schema: dict[str, Any] = json.loads((SCHEMA_DIR / f"{spec.model}.json").read_text())
    jsonschema.validate(json.loads(body), schema)
    # The example says exactly what the code would send for the same message.
    assert json.loads(decoded.model_dump_json()).keys() == json.loads(body).keys()


def test_committed_schemas_match_the_code() -> None:
    for name, schema in schemas().items():
        path = SCHEMA_DIR / f"{name}.json"
        assert path.exists(), f"{path} missing: run make schemas"
        assert path.read_text() == render(schema), f"{path} is out of date: run make schemas"


def test_every_generated_file_matches_a_fresh_generation() -> None:
    """Schemas, protocol/protocol.json, the dashboard's and the firmware's protocol tables."""
    fresh = generated()
    problems = []
    for relative, text in fresh.items():
        path = REPO / relative
        if not path.exists():
            problems.append(f"{relative} is missing")
        elif path.read_text(encoding="utf-8") != text:
            problems.append(f"{relative} differs from a fresh generation")
    for path in sorted(SCHEMA_DIR.glob("*.json")):
        if path.relative_to(REPO).as_posix() not in fresh:
            problems.append(f"{path.relative_to(REPO)} is no longer generated (delete it)")
    assert not problems, "; ".join(problems) + ": run make schemas"


def test_topic_table_matches_the_code() -> None:
    text = DOC.read_text()
    for kind, spec in TOPICS.items():
        pattern = spec.pattern.replace("{unit}", "<unit>").replace("{client}", "<client>")
        pattern = pattern.replace("{device}", "<device>")
        row = re.search(rf"^\| {kind} \| `{re.escape(pattern)}` \|(.*)$", text, re.M)
        assert row, f"protocol.md has no topic-table row for {kind}"
        cells = [c.strip() for c in row.group(1).split("|")]
        assert cells[1] == str(spec.qos), f"{kind}: QoS in doc {cells[1]} != code {spec.qos}"
        assert cells[2] == ("yes" if spec.retained else "no"), f"{kind}: retained flag differs"


def test_the_doc_names_the_version_and_the_generated_table() -> None:
    text = DOC.read_text()
    assert text.startswith(f"# gridfleet protocol, version {PROTOCOL_VERSION}\n")
    assert f'protocol version, `"{PROTOCOL_VERSION}"`' in text
    assert f"this document is `{PROTOCOL_VERSION}`" in text
    for relative in generated():
        if not relative.startswith("protocol/schemas/"):
            assert f"`{relative}`" in text, f"protocol.md does not say where {relative} lives"
