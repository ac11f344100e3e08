"""How a DistanceSensor's ray meets what stands around it: the geometry the Webots double
measures with, read from the GridUnit PROTO as written (tests/support/webots_double.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from support.vrml import Node, Proto

Box = tuple[float, float, float, float]  # x0, y0, x1, y1 (m)


@dataclass(frozen=True)
class Ray:
    """A distance sensor of the GridUnit PROTO: where it sits and looks, and its lookup table."""

    name: str
    x: float
    y: float
    heading: float
    table: tuple[tuple[float, float], ...]  # (distance m, value)

    @property
    def range_m(self) -> float:
        return self.table[-1][0]

    def value(self, distance: float) -> float:
        """The sensor's value for an object `distance` away (the lookup table, interpolated)."""
        if distance >= self.range_m:
            return self.table[-1][1]
        for (d0, v0), (d1, v1) in zip(self.table, self.table[1:], strict=False):
            if d0 <= distance <= d1:
                return v0 + (v1 - v0) * (distance - d0) / (d1 - d0)
        return self.table[0][1]


def numbers(value: object) -> list[float]:
    """The numbers of a field's value (a vector, a colour, a lookup table)."""
    items = list(value) if isinstance(value, tuple | list) else []
    return [float(v) for v in items if isinstance(v, float)]


def unit_geometry(proto: Proto) -> tuple[float, list[Ray]]:
    """The GridUnit's body side and its distance sensors, as its PROTO file places them."""
    body = next(n for n in proto.body.nodes() if n.def_name == "BODY")
    geometry = body.fields["geometry"]
    assert isinstance(geometry, Node) and geometry.type == "Box"
    side = numbers(geometry.fields["size"])[0]
    rays = []
    for node in proto.body.nodes():
        if node.type != "DistanceSensor":
            continue
        x, y, _ = numbers(node.fields["translation"])
        rotation = numbers(node.fields.get("rotation", (0.0, 0.0, 1.0, 0.0)))
        assert rotation[:3] == [0.0, 0.0, 1.0], "a sensor turned about z only"
        table = numbers(node.fields["lookupTable"])
        rows = tuple((table[i], table[i + 1]) for i in range(0, len(table), 3))
        name = node.fields["name"]
        assert isinstance(name, tuple) and isinstance(name[0], str)
        rays.append(Ray(name[0], x, y, rotation[3], rows))
    return side, rays


def _slab(origin: float, step: float, low: float, high: float) -> tuple[float, float]:
    """The ray's entry and exit parameters between two parallel lines (infinite if parallel)."""
    if abs(step) < 1e-12:
        return (-math.inf, math.inf) if low <= origin <= high else (math.inf, -math.inf)
    t0, t1 = (low - origin) / step, (high - origin) / step
    return (min(t0, t1), max(t0, t1))


def hit(
    px: float, py: float, dx: float, dy: float, box: tuple[float, float, float, float]
) -> float:
    """How far along the unit vector (dx, dy) from (px, py) the ray enters `box` (inf: never)."""
    x0, y0, x1, y1 = box
    ax, bx = _slab(px, dx, x0, x1)
    ay, by = _slab(py, dy, y0, y1)
    enter, leave = max(ax, ay), min(bx, by)
    return enter if enter <= leave and leave >= 0 and enter >= 0 else math.inf


def to_wall(floor: Box, px: float, py: float, dx: float, dy: float) -> float:
    """How far the ray from (px, py) along (dx, dy) runs inside the floor to the arena's wall."""
    x0, y0, x1, y1 = floor
    ts = []
    if dx > 1e-12:
        ts.append((x1 - px) / dx)
    if dx < -1e-12:
        ts.append((x0 - px) / dx)
    if dy > 1e-12:
        ts.append((y1 - py) / dy)
    if dy < -1e-12:
        ts.append((y0 - py) / dy)
    return min(ts)
