"""Every PROTO in the repository loads in Webots without a PROTO error.

Webots checks each interface field of a PROTO when it builds one (`WbProtoModel::verifyAliasing`,
Webots R2023b): a field declared with `field` that no `IS` statement of the body links is an
error, "PROTO parameter '…' has no matching IS field", once per instance. A field only a
controller reads (through the Supervisor API) is declared `unconnectedField`, which Webots'
reference (PROTO Definition, IS Statements) documents for that purpose and its own PROTOs use
(RoadLine's `color`, `type`, `width`). Webots skips the check for procedural PROTOs (those
with template statements); the reader here refuses them, so one added later fails this test
instead of passing unchecked.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from support.paths import REPO
from support.vrml import Proto, VrmlError, read_proto

# Folders that are not the project's own files (see .gitignore): installed packages, builds.
NOT_SHIPPED = {"node_modules", "build", "dist", "__pycache__", "test-artifacts"}


def proto_files() -> list[Path]:
    """Every .proto file of the checkout, wherever it is."""
    found: list[Path] = []
    for folder, dirs, files in os.walk(REPO):
        dirs[:] = [d for d in dirs if not d.startswith(".") and d not in NOT_SHIPPED]
        found += [Path(folder) / name for name in files if name.endswith(".proto")]
    return sorted(found)


PROTO_FILES = proto_files()


def proto_of(path: Path) -> Proto:
    return read_proto(path.read_text(encoding="utf-8"))


def test_the_protos_the_worlds_use_are_all_found() -> None:
    names = {p.relative_to(REPO).as_posix() for p in PROTO_FILES}
    assert {
        "robots/webots/protos/GridUnit.proto",
        "robots/webots/protos/GridLed.proto",
        "robots/webots/protos/GridObstacle.proto",
    } <= names


def problems(proto: Proto) -> list[str]:
    """What Webots would report on building `proto`, and declarations that say what is not so."""
    linked = proto.links()
    found = [
        f"{name}: no IS link, and not declared unconnectedField"
        for name, keyword in proto.keywords.items()
        if name not in linked and keyword != "unconnectedField"
    ]
    # Webots: "It is an error for an IS statement to refer to a non-existent interface field".
    found += [f"IS {name}: no such PROTO field" for name in sorted(linked - set(proto.interface))]
    # `unconnectedField` says that nothing in the body uses the field: keep it true.
    found += [
        f"{name}: linked by IS, yet declared unconnectedField"
        for name, keyword in proto.keywords.items()
        if name in linked and keyword == "unconnectedField"
    ]
    return found


@pytest.mark.parametrize("path", PROTO_FILES, ids=lambda p: p.name)
def test_every_proto_field_is_linked_or_declared_unconnected(path: Path) -> None:
    proto = proto_of(path)
    assert proto.name == path.stem  # Webots: "PROTO identifier does not match filename"
    assert problems(proto) == [], path.relative_to(REPO).as_posix()


def test_the_grid_units_controller_fields_are_unconnected_and_keep_their_defaults() -> None:
    # The controller reads these through the Supervisor API (settings.read_settings); nothing in
    # the PROTO's body uses them. Their types and defaults are what the controller has read.
    proto = proto_of(REPO / "robots" / "webots" / "protos" / "GridUnit.proto")
    controller_only = {
        "capacity": ("SFFloat", (1.0,)),
        "stepPeriod": ("SFFloat", (1.0,)),
        "map": ("MFString", []),
        "broker": ("SFString", ("",)),
        "root": ("SFString", ("gridfleet",)),
        "mirror": ("SFBool", (False,)),
        "battery": ("SFBool", (False,)),
        "batteryPct": ("SFFloat", (100.0,)),
        "movePct": ("SFFloat", (0.5,)),
        "idlePctPerS": ("SFFloat", (0.01,)),
        "chargePctPerS": ("SFFloat", (2.0,)),
        "chargers": ("MFVec2f", []),
    }
    for name, declared in controller_only.items():
        assert proto.keywords[name] == "unconnectedField", name
        assert proto.interface[name] == declared, name
    assert {n for n, k in proto.keywords.items() if k == "unconnectedField"} == set(controller_only)


def test_the_check_finds_what_webots_would_report() -> None:
    text = """#VRML_SIM R2023b utf8
PROTO Probe [
  field SFVec3f  translation 0 0 0
  field SFFloat  capacity    1.0  # read by a controller only, yet a plain field
  unconnectedField SFString name ""
]
{
  Solid {
    translation IS translation
    name IS name
    children [ Shape { geometry Box { size IS size } } ]
  }
}
"""
    assert problems(read_proto(text)) == [
        "capacity: no IS link, and not declared unconnectedField",
        "IS size: no such PROTO field",
        "name: linked by IS, yet declared unconnectedField",
    ]
    procedural = text.replace("1.0  #", "%<= 1 >%  #")
    with pytest.raises(VrmlError, match="line 4: a template statement"):
        read_proto(procedural)
