"""gridfleet's released squares as VDA 5050 orders, stitched as the specification requires.

gridfleet releases a unit a few squares at a time and takes none back until the unit's state shows
it left them (protocol.md §4.4). VDA 5050's *base* (released nodes) can never be taken back
either, so every square gridfleet releases becomes a base node once, in order, and nothing else
does: the planned squares become the *horizon* (`released: false`), which the vehicle may not
drive. A vehicle therefore never holds more base than gridfleet released to its unit, and the
stop and the planner keep control exactly as they do for gridfleet's own units.

Stitching (VDA 5050 2.0 §6.6): an update keeps the order id, counts `orderUpdateId` up by one,
starts with the last base node already sent (the same `nodeId` and `sequenceId`) and changes no
base node sent before; sequence ids count nodes even and edges odd along the whole order. A new
order (a new id, update 0) starts at the square the vehicle stands on.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from gridfleet.grid import Cell
from gridfleet.protocol import Action
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.wire import Headers

ANY_THETA = 3.141592  # allowedDeviationTheta: pi, cut within the schemas' bound


def node_id(cell: Cell) -> str:
    """The id of a square's node: the same square is the same node in every order."""
    return f"sq-{cell.x}-{cell.y}"


@dataclass
class _Base:
    """What the current order has released: its base nodes, in order, with sequence ids."""

    order_id: str
    update_id: int = 0
    cells: list[Cell] = field(default_factory=list)
    horizon: list[Cell] = field(default_factory=list)  # as last sent
    action: Action | None = None  # as last sent
    # The action the vehicle already has on a released base node: an update repeats its last base
    # node (the stitching node), and an action on it again is a second action with the same id
    # (vda-5050-lib 1.4.0 then runs the copy after the first and recurses until it crashes).
    given: Action | None = None


class OrderStitcher:
    """One vehicle's orders: a new one, or the next update of the current one."""

    def __init__(
        self,
        headers: Headers,
        frame: Frame,
        prefix: str,
        action_parameters: Mapping[str, str | float | bool] | None = None,
    ) -> None:
        self.headers = headers
        self.frame = frame
        self.action_parameters = dict(action_parameters or {})
        self.prefix = prefix  # order ids are `<prefix>-<n>`: unique per adapter run
        self._orders = 0
        self._base: _Base | None = None

    @property
    def order_id(self) -> str | None:
        """The current order's id (None before the first)."""
        return None if self._base is None else self._base.order_id

    @property
    def base(self) -> tuple[Cell, ...]:
        """The squares released so far on the current order, from its first node."""
        return () if self._base is None else tuple(self._base.cells)

    def adds(
        self, position: Cell, released: list[Cell], planned: list[Cell], action: Action | None
    ) -> bool:
        """Whether `order` would send the vehicle anything for this release (changing nothing)."""
        if self._base is None:
            return True
        try:
            new = self._beyond_base(position, released)
        except ValueError:
            return True  # refused by `order` then
        return bool(new) or planned != self._base.horizon or action != self._base.action

    def end(self) -> None:
        """The current order is over (done, cancelled, or the vehicle lost it): the next is new."""
        self._base = None

    def order(
        self,
        position: Cell,
        released: list[Cell],
        planned: list[Cell],
        action: Action | None,
        now: float,
    ) -> dict[str, Any] | None:
        """The order to send for gridfleet's latest release, or None when it adds nothing.

        `released` and `planned` are gridfleet's squares beyond the unit's `position`. Squares the
        current base already holds are not released again; a release that does not continue the
        base is refused (gridfleet never takes a released square back, so it would be a bug).
        """
        if self._base is None:
            self._orders += 1
            self._base = _Base(f"{self.prefix}-{self._orders}", 0, [position])
            new = list(released)
            first = True
        else:
            new = self._beyond_base(position, released)
            if not new and planned == self._base.horizon and action == self._base.action:
                return None  # it would say again what the vehicle has
            self._base.update_id += 1
            first = False
        stitch = len(self._base.cells) - 1  # the last base node already sent (or the start)
        self._base.cells += new
        self._base.horizon, self._base.action = list(planned), action
        cells = self._base.cells[stitch:] + list(planned)
        released_count = len(self._base.cells) - stitch
        return self._message(cells, stitch, released_count, action, now, first)

    def _beyond_base(self, position: Cell, released: list[Cell]) -> list[Cell]:
        """gridfleet's released squares that the base does not hold yet."""
        assert self._base is not None
        path = [position, *released]
        held = self._base.cells
        # The base's tail from the unit's square on must be what gridfleet releases now.
        if position in held:
            start = len(held) - 1 - held[::-1].index(position)
            tail = held[start:]
            if path[: len(tail)] != tail[: len(path)]:
                raise ValueError(f"release {path} does not continue the base {held}")
            return path[len(tail) :]
        raise ValueError(f"the unit at {list(position)} is not on its order's base {held}")

    def _message(
        self,
        cells: list[Cell],
        stitch: int,
        released_count: int,
        action: Action | None,
        now: float,
        first: bool,
    ) -> dict[str, Any]:
        assert self._base is not None
        nodes, edges = [], []
        route = self._base.cells[: stitch + 1] + cells[1:]  # the whole order, from its start
        for i, cell in enumerate(cells):
            sequence = 2 * (stitch + i)
            x, y = self.frame.position(cell)
            # The official 2.0.0 state schema requires a theta in nodeStates' positions, which a
            # vehicle copies from the order: the heading it arrives with (0 at the start), any
            # orientation allowed (a vehicle turns as it must).
            g = stitch + i
            theta = self.frame.heading(route[g - 1], cell) if g > 0 else 0.0
            node: dict[str, Any] = {
                "nodeId": node_id(cell),
                "sequenceId": sequence,
                "released": i < released_count,
                "nodePosition": {
                    "x": x,
                    "y": y,
                    "theta": theta,
                    "allowedDeviationTheta": ANY_THETA,
                    "mapId": self.frame.map_id,
                },
                "actions": [],
            }
            stitching = i == 0 and not first
            if (
                action is not None
                and cell == action.square
                and i == len(cells) - 1
                and not (stitching and action == self._base.given)
            ):
                node["actions"] = [_vda_action(action, self.action_parameters)]
                if i < released_count:
                    self._base.given = action
            nodes.append(node)
            if i > 0:
                prev = cells[i - 1]
                edges.append(
                    {
                        "edgeId": f"{node_id(prev)}_{node_id(cell)}",
                        "sequenceId": sequence - 1,
                        "released": i < released_count,
                        "startNodeId": node_id(prev),
                        "endNodeId": node_id(cell),
                        "orientation": self.frame.heading(prev, cell),
                        "actions": [],
                    }
                )
        return {
            **self.headers("order", now),
            "orderId": self._base.order_id,
            "orderUpdateId": 0 if first else self._base.update_id,
            "nodes": nodes,
            "edges": edges,
        }


def _vda_action(action: Action, extra: Mapping[str, str | float | bool]) -> dict[str, Any]:
    """gridfleet's pick or drop as VDA 5050's predefined `pick`/`drop` action (blocking: HARD),
    with the vehicle's own parameters (its station and load types) beside gridfleet's."""
    return {
        "actionId": f"{action.kind}-{action.job_id}",
        "actionType": action.kind,
        "blockingType": "HARD",
        "actionParameters": [
            {"key": "loadId", "value": action.job_id},
            {"key": "weight", "value": action.mass_kg},
            *({"key": key, "value": value} for key, value in extra.items()),
        ],
    }
