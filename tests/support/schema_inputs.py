"""Messages made from the protocol's JSON Schemas (protocol/schemas/), for every component's edges.

`messages(kind)` draws what the schema of a topic kind allows (hypothesis-jsonschema), optional
fields absent or present, every allowed type and range; `near_misses(kind)` draws those with one
thing changed (a field dropped, a value of another type or an unknown one, an extra key) and now
and then a payload that is no JSON object at all. Whether a drawn message is valid is for the
oracle to say (`allowed`): jsonschema's Draft 2020-12 validator over the same schema.

Two things stand between the schemas and the tools, both fixed here rather than in the schemas:
hypothesis-jsonschema reads draft 7, so a square's `prefixItems` (2020-12) is given to it as a
draft-7 tuple (`items` as a list, no additional items); and Python's `re.search`, which
jsonschema uses for `pattern`, lets `$` match before a final newline where ECMA-262 (the
language of JSON Schema patterns) does not, so the oracle reads each final `$` as `\\Z`. And the
oracle checks the `date-time` format (RFC 3339) itself: jsonschema asserts no format by default.
"""

from __future__ import annotations

import copy
import json
import os
import re
from collections.abc import Callable, Mapping, Sequence
from datetime import datetime
from functools import cache
from typing import Any

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis_jsonschema import from_schema
from jsonschema import Draft202012Validator, FormatChecker

from support.paths import REPO

# `make test-fast` sets it: each schema-edge test draws a quarter of its messages there (the
# first ones of the same fixed sequence); `make test` draws them all.
FEWER_EXAMPLES = "GRIDFLEET_FEWER_EXAMPLES"


def edge_examples(examples: int) -> int:
    """How many messages a schema-edge test asking for `examples` draws in this run."""
    return max(5, examples // 4) if os.environ.get(FEWER_EXAMPLES) else examples


def edge_settings(examples: int) -> settings:
    """How every schema-edge test draws: `examples` messages (`edge_examples`), the same ones on
    every run (CI sees what a developer saw), no deadline (a loaded machine), no example
    database."""
    return settings(
        max_examples=edge_examples(examples),
        deadline=None,
        database=None,
        derandomize=True,
        suppress_health_check=[
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
            HealthCheck.filter_too_much,
        ],
    )


Json = Any
TABLE: dict[str, Any] = json.loads((REPO / "protocol" / "protocol.json").read_text("utf-8"))
# A key no schema names: every object of the protocol forbids unknown fields.
EXTRA_KEY = "zz_not_in_the_schema"


def schema_of(kind: str) -> dict[str, Any]:
    """The JSON Schema of the messages on topics of `kind` (protocol.json's `topics`)."""
    spec = TABLE["topics"][kind]
    if spec["schema"] is None:
        raise ValueError(f"topic kind {kind!r} carries {spec['payload']}, not JSON")
    return _load(spec["schema"])


@cache
def _load(path: str) -> dict[str, Any]:
    loaded: dict[str, Any] = json.loads((REPO / "protocol" / path).read_text("utf-8"))
    return loaded


def _walk(node: Json, change: Callable[[dict[str, Any]], None]) -> None:
    """Apply `change` to every schema object under `node` (itself included), in place."""
    if isinstance(node, dict):
        change(node)
        for value in node.values():
            _walk(value, change)
    elif isinstance(node, list):
        for value in node:
            _walk(value, change)


def _as_draft7_tuple(node: dict[str, Any]) -> None:
    if "prefixItems" in node:
        node["items"] = node.pop("prefixItems")
        node["additionalItems"] = False


def _ecma_end(node: dict[str, Any]) -> None:
    pattern = node.get("pattern")
    if isinstance(pattern, str):
        node["pattern"] = _ecma_pattern(pattern)
    keyed = node.get("patternProperties")
    if isinstance(keyed, dict):  # the keys of an id-keyed map: the same rule
        node["patternProperties"] = {_ecma_pattern(k): v for k, v in keyed.items()}


def _ecma_pattern(pattern: str) -> str:
    """`pattern` with a final `$` read as ECMA-262 does: the end of the text, not of a line."""
    if pattern.endswith("$") and not pattern.endswith("\\$"):
        return pattern[:-1] + "\\Z"
    return pattern


# RFC 3339's date-time (section 5.6), which JSON Schema's `date-time` format names: jsonschema
# checks it only with rfc3339-validator installed, which this checkout does not need otherwise.
RFC3339 = re.compile(
    r"(\d{4})-(\d{2})-(\d{2})[Tt](\d{2}):(\d{2}):(\d{2})(\.\d+)?([Zz]|[+-](\d{2}):(\d{2}))\Z",
    re.ASCII,
)
FORMATS = FormatChecker(formats=())


@FORMATS.checks("date-time")
def _date_time(value: object) -> bool:
    """Whether `value` is an RFC 3339 date-time (a leap second's :60 included); non-strings pass."""
    if not isinstance(value, str):
        return True
    found = RFC3339.match(value)
    if found is None:
        return False
    year, month, day, hour, minute, second = (int(found.group(i)) for i in range(1, 7))
    offset_ok = found.group(9) is None or (int(found.group(9)) < 24 and int(found.group(10)) < 60)
    try:
        datetime(year, month, day, hour, minute, min(second, 59))
    except ValueError:
        return False
    return second <= 60 and offset_ok


@cache
def _oracle(kind: str) -> Draft202012Validator:
    schema = copy.deepcopy(schema_of(kind))
    _walk(schema, _ecma_end)
    return Draft202012Validator(schema, format_checker=FORMATS)


def allowed(kind: str, message: Json) -> bool:
    """Whether the schema of `kind` allows `message` (Draft 2020-12; ECMA-262 pattern ends)."""
    return bool(_oracle(kind).is_valid(message))


def generation_schema(
    kind: str,
    *,
    max_coord: int | None = None,
    narrow: Mapping[Sequence[str], Json] | None = None,
) -> dict[str, Any]:
    """The schema of `kind` as hypothesis-jsonschema reads it, perhaps narrowed (still inside it).

    `max_coord` bounds every square's coordinates (a playfield's size, so squares land on the
    map as well as off it); `narrow` replaces the subschema at each path (keys into the schema,
    e.g. `("properties", "unit")`) with one that allows less.
    """
    schema = copy.deepcopy(schema_of(kind))
    for key in ("$schema", "$id"):
        schema.pop(key, None)
    _walk(schema, _as_draft7_tuple)
    if max_coord is not None:

        def bound(node: dict[str, Any]) -> None:
            items = node.get("items")
            if node.get("type") == "array" and isinstance(items, list) and len(items) == 2:
                for item in items:
                    item["maximum"] = min(item.get("maximum", max_coord), max_coord)

        _walk(schema, bound)
    for path, sub in (narrow or {}).items():
        node = schema
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = sub
    return schema


def messages(
    kind: str,
    *,
    max_coord: int | None = None,
    narrow: Mapping[Sequence[str], Json] | None = None,
) -> st.SearchStrategy[dict[str, Any]]:
    """Messages the schema of `kind` allows (see `generation_schema` for the narrowing)."""
    return from_schema(generation_schema(kind, max_coord=max_coord, narrow=narrow))


def _places(node: Json, path: tuple[str | int, ...] = ()) -> list[tuple[str | int, ...]]:
    """Every path into `node` (the root too): object keys and array indices."""
    out: list[tuple[str | int, ...]] = [path]
    if isinstance(node, dict):
        for key, value in node.items():
            out += _places(value, (*path, key))
    elif isinstance(node, list):
        for index, value in enumerate(node):
            out += _places(value, (*path, index))
    return out


def _at(node: Json, path: Sequence[str | int]) -> Json:
    for key in path:
        node = node[key]
    return node


def _json_type(value: Json) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int | float):
        return "number"
    return type(value).__name__


# A value of every JSON type; a number with a fraction is no integer.
OTHERS: list[Json] = [None, True, 0.5, -7, "", "not-a-value", [], {}, [[0, 0]], {"x": 1}]


@st.composite
def one_changed(draw: st.DrawFn, message: dict[str, Any]) -> dict[str, Any]:
    """`message` with one thing changed: a key dropped, a value retyped or unknown, a key added."""
    out = copy.deepcopy(message)
    places = _places(out)
    how = draw(st.sampled_from(["drop", "retype", "unknown", "extra"]))
    keyed = [p for p in places if p and isinstance(p[-1], str)]
    if how == "drop" and keyed:
        path = draw(st.sampled_from(keyed))
        del _at(out, path[:-1])[path[-1]]
        return out
    if how == "extra":
        objects = [p for p in places if isinstance(_at(out, p), dict)]
        path = draw(st.sampled_from(objects))
        _at(out, path)[EXTRA_KEY] = draw(st.sampled_from(OTHERS))
        return out
    inner = [p for p in places if p]
    if not inner:
        return out
    path = draw(st.sampled_from(inner))
    now = _at(out, path)
    if how == "unknown" and isinstance(now, str):
        value: Json = draw(st.sampled_from(["no-such-value", "", "x" * 600, "bad/id", "!"]))
    elif how == "unknown" and isinstance(now, int | float) and not isinstance(now, bool):
        value = draw(st.sampled_from([-1, -0.5, 10**20, 4096]))
    else:
        value = draw(st.sampled_from([v for v in OTHERS if _json_type(v) != _json_type(now)]))
    _at(out, path[:-1])[path[-1]] = value
    return out


# What is no message at all: not JSON, not UTF-8, not an object, or nested beyond reason.
GARBAGE: list[bytes] = [
    b"",
    b"{",
    b"\xff\xfe\x00",
    b"null",
    b"[]",
    b'"text"',
    b"42",
    b'{"header": null}',
    b"[" * 3000 + b"]" * 3000,
    b'{"a": NaN}',
]


def near_misses(
    kind: str,
    *,
    max_coord: int | None = None,
    narrow: Mapping[Sequence[str], Json] | None = None,
) -> st.SearchStrategy[bytes]:
    """Payloads one step off what the schema of `kind` allows, and some that are no JSON object.

    Mostly invalid; a change the schema still allows (an optional key dropped) is valid, so
    whoever draws one asks `allowed` which it is.
    """
    changed = messages(kind, max_coord=max_coord, narrow=narrow).flatmap(one_changed)
    return st.one_of(
        changed.map(lambda m: json.dumps(m).encode()),
        st.sampled_from(GARBAGE),
    )


def payloads(
    kind: str,
    *,
    max_coord: int | None = None,
    narrow: Mapping[Sequence[str], Json] | None = None,
) -> st.SearchStrategy[bytes]:
    """Valid messages of `kind` and near misses, about half each, as payloads."""
    valid = messages(kind, max_coord=max_coord, narrow=narrow).map(lambda m: json.dumps(m).encode())
    return st.one_of(valid, near_misses(kind, max_coord=max_coord, narrow=narrow))


def parsed(payload: bytes) -> Json:
    """The JSON in `payload`, or a marker that no schema allows when there is none."""
    try:
        return json.loads(payload)
    except (ValueError, RecursionError):
        return NotJson()


class NotJson:
    """What a payload that is no JSON parses to: no schema allows it."""
