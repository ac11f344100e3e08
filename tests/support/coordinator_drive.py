"""Drive the pure coordinator core with protocol messages as bytes, and read what it publishes.

A core made by `make_core` stamps every header with the same fixed time (`support.effects.FIXED`),
so a test can pin exact payloads with `support.effects.published`.
"""

from __future__ import annotations

from collections.abc import Sequence

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.effects import Effects
from gridfleet.coordinator.jobs import Job, JobBook
from gridfleet.coordinator.records import RecordQuery, answer
from gridfleet.coordinator.window import DEFAULT_WINDOW
from gridfleet.coordinator.world import World
from gridfleet.grid import GridMap
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    Connection,
    Factsheet,
    Order,
    Reply,
    Topics,
    UnitState,
    decode,
    encode,
)
from gridfleet.protocol.messages import AuditEntry, AuditQuery, Message, Request

from support.effects import header, stamper

TOPICS = Topics("gridfleet")


def make_core(
    grid: GridMap,
    *,
    jobs: list[Job] | None = None,
    step_s: float = 1.0,
    seed: int = 0,
    window: int = DEFAULT_WINDOW,
) -> CoordinatorCore:
    """A core on `grid` under the root `gridfleet`, order nonce `n`, every header at FIXED."""
    return CoordinatorCore(
        World(grid, step_period_s=step_s, fleet_known_after_s=0.0),
        JobBook(jobs),
        nonce="n",
        seed=seed,
        topics=TOPICS,
        stamp=stamper("coordinator"),
        window=window,
    )


def from_unit(
    core: CoordinatorCore, kind: str, unit_id: str, message: Message | bytes, now: float
) -> Effects:
    """`message` arrives on the unit's topic of `kind` (connection, factsheet, state)."""
    payload = message if isinstance(message, bytes) else encode(message)
    return core.on_message(TOPICS.unit(kind, unit_id), payload, now)


def request(core: CoordinatorCore, kind: str, message: Request | bytes, now: float) -> Effects:
    """`message` arrives on the request topic of `kind` (submit_job, cancel_job, set_goal)."""
    payload = message if isinstance(message, bytes) else encode(message)
    return core.on_message(TOPICS.request(kind), payload, now)


def meet(core: CoordinatorCore, state: UnitState, capacity_kg: float, step_s: float = 1.0) -> None:
    """The unit of `state` says it is online, describes itself and reports its state (at 0 s)."""
    unit_id = state.header.sender
    from_unit(core, "connection", unit_id, Connection(header=header(unit_id), state="online"), 0)
    fs = Factsheet(header=header(unit_id), capacity_kg=capacity_kg, step_period_s=step_s)
    from_unit(core, "factsheet", unit_id, fs, 0.0)
    from_unit(core, "state", unit_id, state, 0.0)


def step_hearing_itself(core: CoordinatorCore, now: float) -> Effects:
    """One step whose own status comes back to the core, as the broker sends it (its link works)."""
    effects = core.step(now)
    own = TOPICS.fleet("coordinator")
    for out in effects.publish:
        if out.topic == own:
            core.on_message(out.topic, out.payload, now)
    return effects


def orders_in(effects: Effects) -> dict[str, Order]:
    """The orders among `effects`, by unit."""
    out = {}
    for m in effects.publish:
        kind, unit = TOPICS.parse(m.topic)
        if kind == "order" and unit is not None:
            out[unit] = decode(Order, m.payload)
    return out


def reply_in(effects: Effects) -> Reply:
    """The one reply among `effects`."""
    (reply,) = [decode(Reply, m.payload) for m in effects.publish if "/replies/" in m.topic]
    return reply


class AuditRows:
    """An in-memory audit store (records.RecordsDesk) over entries numbered from 1."""

    def __init__(self, entries: Sequence[AuditEntry] = ()) -> None:
        self.numbered = list(enumerate(entries, start=1))

    def rows(self, query: RecordQuery, limit: int) -> list[tuple[int, AuditEntry]]:
        """Up to `limit` entries in `query`'s range, of its actor, after its cursor, by id."""
        assert isinstance(query.query, AuditQuery)
        actor, after = query.query.actor, query.after or 0
        return [
            (i, e)
            for i, e in self.numbered
            if query.since <= e.at.timestamp() < query.until and i > after
            if actor in (None, e.actor)
        ][:limit]


def answered(
    core: CoordinatorCore, topic: str, payload: bytes, desk: AuditRows | None = None
) -> tuple[list[Outbound], Effects]:
    """What the core publishes for one message, its record queries answered from `desk` as the
    shell answers them from its stores; and the core's Effects."""
    effects = core.on_message(topic, payload, 0.0)
    pages = [answer(r, desk or AuditRows(), core.say) for r in effects.records]
    return [*effects.publish, *(p for p in pages if p is not None)], effects
