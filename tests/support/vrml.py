"""A small reader of Webots' VRML-like files (.wbt worlds, .proto files), for tests.

It reads what gridfleet writes and ships: comments, EXTERNPROTO lines, PROTO interfaces, nodes
with DEF/USE, fields whose value is a node, a `[ ... ]` list, `IS name`, or numbers, strings
and booleans. Anything else (an unclosed brace or bracket, a stray token, a field given twice,
a template statement of a procedural PROTO) raises VrmlError naming the line, so a file that
reads here has balanced nodes and lists.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Union

Scalar = float | str | bool
Value = Union["Node", "Is", tuple[Scalar, ...], list[Union["Node", Scalar]]]

_TOKEN = re.compile(
    r'(?P<string>"(?:[^"\\]|\\.)*")|(?P<punct>[{}\[\]])|(?P<word>[^\s{}\[\],"#]+)|(?P<bad>")'
)
TEMPLATE_OPENINGS = ("%<", "%{")  # JavaScript and Lua template statements of Webots PROTOs
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


class VrmlError(ValueError):
    """The text is not a VRML file this reader understands; the message names the line."""


@dataclass(frozen=True)
class Is:
    """A PROTO body's `IS name`: the value of the PROTO field `name`."""

    name: str


@dataclass
class Node:
    """A node: its type, its DEF name if any, and its fields in the order given."""

    type: str
    fields: dict[str, Value] = field(default_factory=dict)
    def_name: str | None = None

    def nodes(self) -> list[Node]:
        """This node and every node inside it, depth first."""
        found = [self]
        for value in self.fields.values():
            items = [value] if isinstance(value, Node) else value if isinstance(value, list) else []
            for item in items:
                if isinstance(item, Node):
                    found += item.nodes()
        return found


@dataclass
class Proto:
    """A PROTO: its interface (field name: type and default) and its body."""

    name: str
    interface: dict[str, tuple[str, Value]]
    body: Node
    externprotos: list[str]
    # Each field's declaring keyword: `field`, `unconnectedField`, …
    keywords: dict[str, str] = field(default_factory=dict)

    def links(self) -> set[str]:
        """The interface fields the body's `IS` statements name."""
        return {
            value.name
            for node in self.body.nodes()
            for value in node.fields.values()
            if isinstance(value, Is)
        }


@dataclass
class World:
    """A .wbt file: its header line, EXTERNPROTO paths and top-level nodes."""

    header: str
    externprotos: list[str]
    nodes: list[Node]

    def of_type(self, kind: str) -> list[Node]:
        """The top-level nodes of type `kind`, in file order."""
        return [n for n in self.nodes if n.type == kind]


class _Tokens:
    def __init__(self, text: str) -> None:
        self.items: list[tuple[str, str, int]] = []  # (kind, text, line)
        for number, line in enumerate(text.splitlines(), start=1):
            code = _strip_comment(line)
            for m in _TOKEN.finditer(code):
                kind = m.lastgroup or "bad"
                if kind == "bad":
                    raise VrmlError(f"line {number}: unclosed string")
                self.items.append((kind, m.group(), number))
        self.at = 0

    def peek(self, ahead: int = 0) -> tuple[str, str, int] | None:
        i = self.at + ahead
        return self.items[i] if i < len(self.items) else None

    def take(self, expected: str | None = None) -> tuple[str, str, int]:
        token = self.peek()
        if token is None:
            raise VrmlError(f"end of file: expected {expected or 'more'}")
        if expected is not None and token[1] != expected:
            raise VrmlError(f"line {token[2]}: expected {expected!r}, found {token[1]!r}")
        self.at += 1
        return token


def _strip_comment(line: str) -> str:
    """The line without its `#` comment (a `#` inside a string stays)."""
    quoted = False
    for i, ch in enumerate(line):
        if ch == '"' and (i == 0 or line[i - 1] != "\\"):
            quoted = not quoted
        elif ch == "#" and not quoted:
            return line[:i]
    return line


def _scalar(kind: str, text: str) -> Scalar | None:
    if kind == "string":
        return re.sub(r"\\(.)", r"\1", text[1:-1])
    if text in ("TRUE", "FALSE"):
        return text == "TRUE"
    if _NUMBER.match(text):
        return float(text)
    return None


def _value(tokens: _Tokens) -> Value:
    kind, text, line = tokens.take()
    if kind == "punct" and text != "[":
        raise VrmlError(f"line {line}: expected a value, found {text!r}")
    if text == "[":
        items: list[Node | Scalar] = []
        while (nxt := tokens.peek()) is not None and nxt[1] != "]":
            if nxt[0] == "punct":
                raise VrmlError(f"line {nxt[2]}: unexpected {nxt[1]!r} in a list")
            scalar = _scalar(*nxt[:2])
            if scalar is None:
                items.append(_node(tokens))
            else:
                tokens.take()
                items.append(scalar)
        tokens.take("]")
        return items
    if text == "IS":
        return Is(tokens.take()[1])
    scalar = _scalar(kind, text)
    if scalar is None:
        tokens.at -= 1
        return _node(tokens)
    values = [scalar]
    while (nxt := tokens.peek()) is not None and (more := _scalar(*nxt[:2])) is not None:
        values.append(more)
        tokens.take()
    return tuple(values)


def _node(tokens: _Tokens) -> Node:
    kind, text, line = tokens.take()
    def_name = None
    if text == "USE":
        return Node("USE", {"name": (tokens.take()[1],)})
    if text == "DEF":
        def_name = tokens.take()[1]
        kind, text, line = tokens.take()
    if kind != "word" or _scalar(kind, text) is not None:
        raise VrmlError(f"line {line}: expected a node type, found {text!r}")
    node = Node(text, def_name=def_name)
    tokens.take("{")
    while (nxt := tokens.peek()) is not None and nxt[1] != "}":
        name_kind, name, name_line = tokens.take()
        if name_kind != "word" or _scalar(name_kind, name) is not None:
            raise VrmlError(f"line {name_line}: expected a field name in {text}, found {name!r}")
        if name in node.fields:
            raise VrmlError(f"line {name_line}: field {name!r} given twice in {text}")
        node.fields[name] = _value(tokens)
    tokens.take("}")
    return node


def _externprotos(tokens: _Tokens) -> list[str]:
    found = []
    while (nxt := tokens.peek()) is not None and nxt[1] in ("EXTERNPROTO", "IMPORTABLE"):
        if tokens.take()[1] == "IMPORTABLE":
            tokens.take("EXTERNPROTO")
        kind, text, line = tokens.take()
        if kind != "string":
            raise VrmlError(f"line {line}: EXTERNPROTO needs a quoted path")
        path = _scalar(kind, text)
        assert isinstance(path, str)
        found.append(path)
    return found


def _header(text: str) -> str:
    first = text.splitlines()[0] if text else ""
    if not re.fullmatch(r"#VRML_SIM R20\d\d[ab] utf8", first):
        raise VrmlError(f"line 1: not a Webots header: {first!r}")
    return first


def read_world(text: str) -> World:
    """Read a .wbt file; VrmlError on anything unbalanced or unexpected."""
    header = _header(text)
    tokens = _Tokens(text)
    externs = _externprotos(tokens)
    nodes = []
    while tokens.peek() is not None:
        nodes.append(_node(tokens))
    return World(header, externs, nodes)


def read_proto(text: str) -> Proto:
    """Read a .proto file with one PROTO; VrmlError on anything unbalanced or unexpected."""
    _header(text)
    for number, line in enumerate(text.splitlines(), start=1):
        # A procedural PROTO's body is a program's output, not VRML until Webots runs it.
        if any(opening in _strip_comment(line) for opening in TEMPLATE_OPENINGS):
            raise VrmlError(f"line {number}: a template statement (procedural PROTO)")
    tokens = _Tokens(text)
    externs = _externprotos(tokens)
    tokens.take("PROTO")
    name = tokens.take()[1]
    tokens.take("[")
    interface: dict[str, tuple[str, Value]] = {}
    keywords: dict[str, str] = {}
    while (nxt := tokens.peek()) is not None and nxt[1] != "]":
        keyword = tokens.take()[1]
        if keyword not in ("field", "vrmlField", "hiddenField", "unconnectedField"):
            raise VrmlError(f"line {nxt[2]}: expected a field declaration, found {keyword!r}")
        kind = tokens.take()[1]
        field_name = tokens.take()[1]
        if field_name in interface:
            raise VrmlError(f"line {nxt[2]}: PROTO field {field_name!r} declared twice")
        interface[field_name] = (kind, _value(tokens))
        keywords[field_name] = keyword
    tokens.take("]")
    tokens.take("{")
    body = _node(tokens)
    tokens.take("}")
    if tokens.peek() is not None:
        raise VrmlError(f"line {tokens.take()[2]}: text after the PROTO's body")
    return Proto(name, interface, body, externs, keywords)
