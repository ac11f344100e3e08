"""Closed zones (coordinator/zones.py, protocol.md §5.11, §6.12, §6.13): the pure core's exact
decisions, with the real unit core (robots' UnitLogic) on a simulated world as ground truth.

A closed zone's squares are walls for every unit outside it; a unit inside leaves by the
shortest way through the zone's own squares, or holds and says why; jobs with an errand inside
wait `zone_closed`, jobs the zones cut off wait `unreachable`; everything resumes once it opens.
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest
from prometheus_client import generate_latest
from prometheus_client.parser import text_string_to_metric_families

from gridfleet.accounts import default_accounts
from gridfleet.coordinator.audit import Identity
from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.effects import Effects
from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.metrics import CoordinatorMetrics
from gridfleet.coordinator.planning.validate import validate_windows, validate_zones
from gridfleet.coordinator.store import JobStore
from gridfleet.coordinator.window import MAX_WINDOW
from gridfleet.coordinator.world import World
from gridfleet.coordinator.zones import ZoneBook, leaving_moves, zone_refusal
from gridfleet.grid import Cell, GridMap
from gridfleet.paths import DistanceFieldCache
from gridfleet.protocol import (
    CloseZone,
    OpenZone,
    Order,
    Reply,
    Routes,
    SetGoal,
    SubmitJob,
    ZonesView,
    decode,
    encode,
)
from gridfleet.protocol.constants import MAX_ZONES
from gridfleet.robots.unit import UnitLogic

from support.coordinator_drive import TOPICS, from_unit, make_core, meet, orders_in, reply_in
from support.coordinator_fakes import ROOM_ROWS, Yard
from support.effects import FIXED, header, stamper

OPEN_FLOOR = GridMap.from_rows(["." * 9] * 5)


class Site:
    """A core and a yard of real unit cores on `grid`; each `step` delivers every order, lets
    every unit step and sends its state back, as a fleet on reliable messages does."""

    def __init__(self, grid: GridMap, starts: dict[str, Cell], *, window: int = 1) -> None:
        self.grid = grid
        self.core = make_core(grid, window=window)
        self.yard = Yard(grid, [UnitLogic(u, grid, c, 10.0, 1.0) for u, c in starts.items()])
        self.now = 0.0
        self.ids = iter(range(1, 10_000))
        self.routes: dict[str, object] = {}
        self.orders: list[dict[str, Order]] = []
        self.trail: dict[str, list[Cell]] = {u: [c] for u, c in starts.items()}
        for u in starts:
            self.yard.units[u].start(0.0)
            meet(self.core, self.yard.state(u), 10.0)

    def ask(self, kind: str, model: type, **fields: object) -> Reply:
        req = model(header=header("op"), request_id=f"r{next(self.ids)}", reply_to="op", **fields)
        payload = req.model_dump_json().encode()
        return reply_in(self.core.on_message(TOPICS.request(kind), payload, self.now))

    def close(self, name: str, first: Cell, last: Cell, reason: str = "cleaning") -> Reply:
        return self.ask("close_zone", CloseZone, name=name, first=first, last=last, reason=reason)

    def open(self, name: str) -> Reply:
        return self.ask("open_zone", OpenZone, name=name)

    def submit(self, pickup: Cell, dropoff: Cell, job_id: str, mass_kg: float = 1.0) -> Reply:
        return self.ask(
            "submit_job", SubmitJob, pickup=pickup, dropoff=dropoff, mass_kg=mass_kg, job_id=job_id
        )

    def goal(self, unit: str, target: Cell) -> Reply:
        return self.ask("set_goal", SetGoal, unit=unit, target=target)

    def step(self) -> dict[str, Order]:
        self.now += 1.0
        effects = self.core.step(self.now)
        orders = orders_in(effects)
        for out in effects.publish:
            if out.topic == TOPICS.fleet("routes"):
                self.routes = dict(decode(Routes, out.payload).routes)
        self.orders.append(orders)
        for uid, order in orders.items():
            self.yard.units[uid].on_order(order, self.now)
        for uid in self.yard.units:
            self.yard.tick(uid, self.now)
            self.trail[uid].append(self.yard.units[uid].position)
            from_unit(self.core, "state", uid, self.yard.state(uid), self.now)
        assert (self.yard.world.prevented, self.yard.world.collisions) == (0, 0)
        return orders

    def run(self, steps: int) -> None:
        for _ in range(steps):
            self.step()

    def note(self, unit: str) -> str | None:
        return self.routes[unit].note  # type: ignore[attr-defined, no-any-return]

    def at(self, unit: str) -> Cell:
        return self.yard.units[unit].position

    def job(self, job_id: str) -> tuple[str, str | None, str | None]:
        job = self.core.jobs.jobs[job_id]
        return job.state, job.wait, job.wait_reason

    def zones_view(self) -> ZonesView:
        return decode(ZonesView, self.core._zones_view().payload)


def rect(first: Cell, last: Cell) -> set[Cell]:
    return {Cell(x, y) for x in range(first.x, last.x + 1) for y in range(first.y, last.y + 1)}


def closing(rid: str, name: str, first: Cell, last: Cell, reason: str = "cleaning") -> CloseZone:
    """A close_zone request from `op`."""
    return CloseZone(
        header=header("op"),
        request_id=rid,
        reply_to="op",
        name=name,
        first=first,
        last=last,
        reason=reason,
    )


def opening(rid: str, name: str) -> OpenZone:
    """An open_zone request from `op`."""
    return OpenZone(header=header("op"), request_id=rid, reply_to="op", name=name)


def asked(
    core: CoordinatorCore, kind: str, req: CloseZone | OpenZone | SubmitJob, now: float = 0.0
) -> Effects:
    """What the core does with one request."""
    return core.on_message(TOPICS.request(kind), encode(req), now)


# ---- closing and opening: the decisions and their codes -----------------------------------------


def test_a_zone_is_closed_with_its_corners_in_order_and_shown_in_the_view() -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 0)})
    reply = site.close("aisle-4", Cell(5, 4), Cell(3, 1))
    assert (reply.accepted, reply.reason, reply.code) == (
        True,
        "zone aisle-4 closed: [3, 1] to [5, 4], 12 squares",
        None,
    )
    zone = site.zones_view().zones[0]
    assert (zone.name, zone.first, zone.last, zone.reason, zone.closed_by, zone.closed_at) == (
        "aisle-4",
        Cell(3, 1),
        Cell(5, 4),
        "cleaning",
        "op",
        FIXED,
    )


def test_closing_a_zone_again_as_it_is_is_accepted_and_changes_nothing() -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 0)})
    first = asked(site.core, "close_zone", closing("a", "aisle-4", Cell(3, 1), Cell(5, 4)))
    assert [name for name, _ in first.zones] == ["aisle-4"]
    version = site.core.zones.version
    # The same rectangle, its corners the other way round, the same reason: a new request.
    again = asked(site.core, "close_zone", closing("b", "aisle-4", Cell(5, 1), Cell(3, 4)))
    reply = reply_in(again)
    assert (reply.accepted, reply.reason, reply.code) == (
        True,
        "zone aisle-4 is already closed, as asked: nothing changed",
        None,
    )
    assert again.zones == () and site.core.zones.version == version
    assert not any(out.topic == TOPICS.fleet("zones") for out in again.publish)
    assert len(site.zones_view().zones) == 1


CONFLICT = "zone aisle-4 is already closed (cleaning): open it first"


@pytest.mark.parametrize(
    ("first", "last", "reason", "code", "words"),
    [
        (
            Cell(3, 1),
            Cell(9, 4),
            "cleaning",
            "bad_square",
            "zone aisle-4: corner last [9, 4] is off the 9x5 map",
        ),
        (Cell(3, 1), Cell(5, 3), "cleaning", "conflict", CONFLICT),  # another rectangle
        (Cell(3, 1), Cell(5, 4), "spill", "conflict", CONFLICT),  # another reason
    ],
)
def test_closing_is_refused_with_its_code_and_changes_nothing(
    first: Cell, last: Cell, reason: str, code: str, words: str
) -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 0)})
    if code == "conflict":
        assert site.close("aisle-4", Cell(3, 1), Cell(5, 4)).accepted
    before = site.zones_view().zones
    reply = site.close("aisle-4", first, last, reason)
    assert (reply.accepted, reply.code, reply.reason) == (False, code, words)
    assert site.zones_view().zones == before


def test_more_than_max_zones_is_refused_invalid() -> None:
    site = Site(GridMap.from_rows(["." * 32] * 9), {"u": Cell(0, 8)})
    for n in range(MAX_ZONES):
        assert site.close(f"z{n}", Cell(n % 32, n // 32), Cell(n % 32, n // 32)).accepted
    reply = site.close("one-more", Cell(0, 8), Cell(1, 8))
    assert (reply.accepted, reply.code) == (False, "invalid")
    assert reply.reason == (
        f"too many zones: {MAX_ZONES} are closed (at most {MAX_ZONES}); open one first, or close "
        "one larger zone"
    )
    assert "one-more" not in site.core.zones.zones


def test_opening_a_zone_not_closed_is_refused_naming_those_closed() -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 0)})
    none = site.open("dock")
    assert (none.accepted, none.code, none.reason) == (
        False,
        "unknown_zone",
        "zone dock is not closed (closed: none is)",
    )
    site.close("aisle-4", Cell(3, 1), Cell(5, 4))
    site.close("aisle-5", Cell(7, 1), Cell(7, 4), "inventory")
    some = site.open("dock")
    assert (some.code, some.reason) == (
        "unknown_zone",
        "zone dock is not closed (closed: aisle-4, aisle-5)",
    )
    opened = site.open("aisle-4")
    assert (opened.accepted, opened.reason) == (
        True,
        "zone aisle-4 opened ([3, 1] to [5, 4], closed: cleaning)",
    )
    assert [z.name for z in site.zones_view().zones] == ["aisle-5"]


def test_a_job_into_a_closed_zone_is_refused_zone_closed_and_not_listed() -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 0)})
    site.close("aisle-4", Cell(3, 1), Cell(5, 4))
    pickup = site.submit(Cell(3, 4), Cell(8, 0), "j1")
    assert (pickup.accepted, pickup.code, pickup.reason) == (
        False,
        "zone_closed",
        "pickup [3, 4] is in zone aisle-4, closed: cleaning",
    )
    dropoff = site.submit(Cell(8, 0), Cell(4, 2), "j2")
    assert (dropoff.code, dropoff.reason) == (
        "zone_closed",
        "dropoff [4, 2] is in zone aisle-4, closed: cleaning",
    )
    goal = site.goal("u", Cell(5, 1))
    assert (goal.code, goal.reason) == (
        "zone_closed",
        "target [5, 1] is in zone aisle-4, closed: cleaning",
    )
    assert site.core.jobs.jobs == {} and site.core.directives.goals == {}


def test_zone_refusal_names_the_first_zone_of_a_square() -> None:
    book = ZoneBook(9, 5)
    assert zone_refusal(book, Cell(3, 4), "pickup") is None
    assert zone_refusal(None, Cell(3, 4), "pickup") is None
    assert book.close(closing("z", "aisle-4", Cell(3, 1), Cell(5, 4)), "op", FIXED).changed
    assert zone_refusal(book, Cell(3, 4), "pickup") == (
        "pickup [3, 4] is in zone aisle-4, closed: cleaning"
    )
    assert book.blocks(Cell(0, 0), Cell(3, 4)) and not book.blocks(Cell(4, 2), Cell(3, 4))


# ---- planning: round, out, or holding ----------------------------------------------------------


def test_a_unit_outside_is_routed_round_a_closed_zone_and_never_enters_it() -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 2)})
    zone = rect(Cell(2, 1), Cell(6, 3))
    site.close("aisle-4", Cell(2, 1), Cell(6, 3))
    assert site.goal("u", Cell(8, 2)).accepted
    site.run(20)
    assert site.at("u") == Cell(8, 2)
    assert not zone & set(site.trail["u"])
    # Round the zone is 12 squares, through it 8: the shortest way with the zone a wall.
    moves = [a for a, b in zip(site.trail["u"], site.trail["u"][1:], strict=False) if a != b]
    assert len(moves) == 12
    assert all(not zone & set(o["u"].released) for o in site.orders if "u" in o)


def test_a_unit_inside_leaves_by_the_shortest_way_through_its_own_zone_only() -> None:
    # Zone aisle-4 spans rows 1-4 of columns 0-3, aisle-5 column 4: from [3, 3] the nearest
    # free square through aisle-5 would be [5, 3] (2 squares), but a unit drives only its own
    # zone's squares: out north to [3, 0] (3 squares).
    site = Site(OPEN_FLOOR, {"u": Cell(3, 3)})
    site.close("aisle-4", Cell(0, 1), Cell(3, 4))
    site.close("aisle-5", Cell(4, 1), Cell(4, 4), "inventory")
    released = []
    for _ in range(5):
        order = site.step().get("u")
        if order is not None and order.released:
            released.append(order.released)
        if site.at("u") == Cell(3, 0):
            break
    assert released == [[Cell(3, 2)], [Cell(3, 1)], [Cell(3, 0)]]
    assert site.trail["u"][-1] == Cell(3, 0)
    texts = [e.text for e in site.core.events.events if e.kind == "zone"]
    assert (
        texts[-1] == "unit u leaving closed zone aisle-4 by the shortest way (3 squares, to [3, 0])"
    )
    site.step()
    assert site.note("u") is None  # out: nothing to say


def test_a_leaving_unit_shows_why_and_the_rest_of_its_way_out() -> None:
    # From [1, 3] out east is 3 squares, north 3 too: of equal ways the first by N E S W.
    site = Site(OPEN_FLOOR, {"u": Cell(1, 3)})
    site.close("aisle-4", Cell(0, 1), Cell(3, 4))
    order = site.step()["u"]
    assert order.released == [Cell(1, 2)]
    route = site.routes["u"]
    assert route.note == "leaving zone aisle-4 (closed: cleaning)"  # type: ignore[attr-defined]
    assert route.planned == [Cell(1, 1), Cell(1, 0)]  # type: ignore[attr-defined]
    assert route.target == Cell(1, 0)  # type: ignore[attr-defined]


ROOM = GridMap.from_rows(["@@@@@@@", "@.....@", "@.....@", "@@@.@@@", "......."])


def test_a_unit_boxed_in_holds_says_why_and_leaves_once_a_way_opens() -> None:
    # The room's only door, [3, 3], is a zone of its own: no way out of the room's zone.
    site = Site(ROOM, {"u": Cell(2, 1)})
    assert site.goal("u", Cell(0, 4)).accepted
    site.close("room", Cell(1, 1), Cell(5, 2))
    site.close("door", Cell(3, 3), Cell(3, 3), "repair")
    site.run(5)
    assert site.at("u") == Cell(2, 1)
    assert site.note("u") == "holding: inside closed zone room and no way out"
    assert all(o["u"].released == [] for o in site.orders[1:] if "u" in o)
    texts = [e.text for e in site.core.events.events if e.kind == "zone"]
    assert "unit u holds inside closed zone room: no way out" in texts
    assert site.open("door").accepted
    site.run(3)
    assert site.trail["u"][-3:] == [Cell(3, 1), Cell(3, 2), Cell(3, 3)]  # out through the door
    site.run(20)
    assert site.at("u") == Cell(0, 4)  # its goal again, the room still closed
    assert not rect(Cell(1, 1), Cell(5, 2)) & set(site.trail["u"][-20:])


def test_an_idle_unit_on_the_way_out_makes_way_and_is_never_given_a_square_inside() -> None:
    # u2 leaves the zone east, to [6, 2] (2 squares; west is 3), where u1 stands: u1, whose goal
    # the zone cuts off, makes way east, never west into the zone.
    grid = GridMap.from_rows(["@@@@@@@@@", "@@@@@@@@@", ".........", "@@@@@@@@@", "@@@@@@@@@"])
    site = Site(grid, {"u1": Cell(6, 2), "u2": Cell(4, 2)})
    site.close("aisle-4", Cell(2, 2), Cell(5, 2))
    assert site.goal("u1", Cell(0, 2)).accepted  # cut off by the zone: it waits
    site.run(8)
    assert site.trail["u2"][:3] == [Cell(4, 2), Cell(5, 2), Cell(5, 2)]
    assert site.at("u2") == Cell(6, 2) and site.at("u1").x > 6
    assert not rect(Cell(2, 2), Cell(5, 2)) & set(site.trail["u1"])
    assert site.note("u1") == (
        "waiting: zone aisle-4 (closed: cleaning) cuts every way to its goal [0, 2]"
    )
    assert site.open("aisle-4").accepted
    site.step()
    assert site.note("u1") is None and site.routes["u1"].target == Cell(0, 2)  # type: ignore[attr-defined]


def test_leaving_moves_never_give_a_square_taken_and_let_the_nearest_go_first() -> None:
    ways = {"far": [Cell(1, 0), Cell(2, 0)], "near": [Cell(2, 0)], "behind": [Cell(1, 0)]}
    taken = {Cell(9, 9)}
    assert leaving_moves(ways, taken) == {"near": Cell(2, 0), "behind": Cell(1, 0)}
    assert leaving_moves({"u": [Cell(9, 9)]}, {Cell(9, 9)}) == {}


# ---- jobs: waiting, and going on once the zone opens ---------------------------------------------


def test_a_queued_job_with_an_errand_inside_waits_with_the_zones_reason_then_is_done() -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 0)})
    assert site.submit(Cell(1, 4), Cell(7, 2), "j1").accepted
    site.close("aisle-4", Cell(6, 0), Cell(8, 4))
    site.run(6)
    assert site.job("j1") == ("queued", "zone_closed", "zone aisle-4 closed: cleaning")
    assert site.at("u") == Cell(0, 0)
    assert site.open("aisle-4").accepted
    site.run(20)
    assert site.job("j1") == ("done", None, None)


def test_a_loaded_unit_keeps_its_load_and_waits_outside_until_its_dropoff_opens() -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 0)})
    assert site.submit(Cell(1, 0), Cell(8, 4), "j1", mass_kg=2.0).accepted
    while site.job("j1")[0] not in ("loaded", "to_dropoff"):
        site.step()
        assert site.now < 10
    site.close("dock", Cell(7, 3), Cell(8, 4), "truck loading")
    site.run(12)
    unit = site.yard.units["u"]
    assert (unit.job_id, unit.load_kg) == ("j1", 2.0)
    assert site.at("u") not in rect(Cell(7, 3), Cell(8, 4))
    assert site.job("j1")[1:] == ("zone_closed", "zone dock closed: truck loading")
    assert (
        site.note("u")
        == "waiting outside: its dropoff [8, 4] is in zone dock (closed: truck loading)"
    )
    site.open("dock")
    site.run(12)
    assert site.job("j1")[0] == "done"


CORRIDOR = GridMap.from_rows(["@@@@@@@@", "........", "@@@@@@@@"])


def test_a_job_the_zones_cut_off_waits_unreachable_and_is_done_once_they_open() -> None:
    site = Site(CORRIDOR, {"u": Cell(0, 1)})
    assert site.submit(Cell(6, 1), Cell(7, 1), "j1").accepted
    site.close("aisle-4", Cell(3, 1), Cell(3, 1))
    site.run(5)
    assert site.job("j1") == (
        "queued",
        "unreachable",
        "zone aisle-4 (closed: cleaning) cuts every way to its pickup [6, 1] from every unit "
        "that can carry 1.0 kg",
    )
    assert site.core.jobs.jobs["j1"].state == "queued"  # waits: never failed nor rejected
    site.open("aisle-4")
    site.run(15)
    assert site.job("j1")[0] == "done"


def test_a_job_submitted_while_zones_cut_it_off_is_accepted_and_waits() -> None:
    site = Site(CORRIDOR, {"u": Cell(0, 1)})
    site.close("aisle-4", Cell(3, 1), Cell(3, 1))
    assert site.submit(Cell(6, 1), Cell(7, 1), "j1").accepted  # only a zone's doing: it waits
    site.step()
    assert site.job("j1")[1] == "unreachable"


# ---- kept across restarts -------------------------------------------------------------------------


def test_the_store_keeps_the_zones_across_a_restart(tmp_path: Path) -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 2)})
    store = JobStore(tmp_path / "jobs.db")
    effects = asked(site.core, "close_zone", closing("z", "aisle-4", Cell(2, 1), Cell(6, 3)))
    store.save_zones(effects.zones)
    store.close()
    again = JobStore(tmp_path / "jobs.db")
    zones = again.load_zones()
    assert [(z.name, z.first, z.last, z.reason, z.closed_by) for z in zones] == [
        ("aisle-4", Cell(2, 1), Cell(6, 3), "cleaning", "op")
    ]
    restarted = CoordinatorCore(
        site.core.world, site.core.jobs, nonce="m", zones=zones, topics=TOPICS
    )
    assert restarted.planner.cache.distance(Cell(0, 2), Cell(8, 2)) == 12  # round it, as before
    (view,) = [
        json.loads(out.payload)
        for out in restarted.on_connect().publish
        if out.topic == TOPICS.fleet("zones")
    ]
    assert [z["name"] for z in view["zones"]] == ["aisle-4"]
    again.save_zones(asked(restarted, "open_zone", opening("o", "aisle-4")).zones)
    assert again.load_zones() == []


def test_a_stored_zone_off_this_map_is_not_in_force_and_can_be_forgotten() -> None:
    wide = ZoneBook(9, 9)
    wide.close(closing("z", "far", Cell(0, 0), Cell(6, 6), "old"), "op", FIXED)
    book = ZoneBook(4, 4, wide.zones.values())
    assert len(book) == 0 and [z.name for z in book.ignored] == ["far"]
    assert book.open("far").accepted and book.take_changes() == (("far", None),)


def test_the_plain_distances_ignore_zones_for_what_a_job_needs_for_good() -> None:
    site = Site(CORRIDOR, {"u": Cell(0, 1)})
    site.close("aisle-4", Cell(3, 1), Cell(3, 1))
    assert isinstance(site.core.map_cache, DistanceFieldCache)
    assert site.core.map_cache.distance(Cell(0, 1), Cell(7, 1)) == 7
    assert site.core.planner.cache.distance(Cell(0, 1), Cell(7, 1)) > 10**6


# ---- the validator, with zones closing mid-run ----------------------------------------------------


def test_the_validator_catches_an_agent_outside_on_or_holding_a_closed_square() -> None:
    closed = rect(Cell(2, 0), Cell(3, 1))
    positions = [Cell(0, 0), Cell(2, 0), Cell(3, 1)]
    windows: list[list[Cell]] = [[Cell(1, 0), Cell(2, 0)], [], [Cell(3, 2)]]
    found = validate_zones(positions, windows, closed)
    assert [(v.kind, v.agents) for v in found] == [("zone", (0,)), ("zone", (1,)), ("zone", (2,))]
    assert validate_zones(positions, windows, closed, inside={1, 2}) == found[:1]
    assert validate_zones([Cell(0, 0)], [[Cell(1, 0)]], closed) == []


def simulate_with_zones(
    seed: int, window: int, p_state: float, p_order: float
) -> tuple[CoordinatorCore, set[str]]:
    """Six units and sixteen jobs on ROOM_ROWS; zone aisle-4 closes at step 4 and opens at step
    70, zone dock closes at step 30 for good. Orders and states are late and lost at random;
    after every step the released windows pass the validator, and no unit that was outside a
    zone when it closed (standing, holding or about to be given a square of it) stands on or
    holds one of its squares until it opens. Returns once every job is final, with the jobs
    that waited for a zone."""
    rng = random.Random(seed)
    grid = GridMap.from_rows(ROOM_ROWS)
    core = make_core(grid, seed=seed, window=window)
    free = grid.free_cells()
    spots = rng.sample(free, 6)
    units = [UnitLogic(f"u{i}", grid, spots[i], 20.0, 1.0) for i in range(6)]
    yard = Yard(grid, units, sensors_see_units=False)
    ids = {u.unit_id: i for i, u in enumerate(units)}
    for u in units:
        u.start(0.0)
        meet(core, yard.state(u.unit_id), u.capacity_kg)
    dock = rect(Cell(8, 8), Cell(9, 9))
    # Three jobs from far corners into aisle-4: under way, loaded, when it closes; the rest at
    # random, some through it.
    into = [(Cell(0, 0), Cell(4, 4)), (Cell(9, 0), Cell(5, 3)), (Cell(0, 9), Cell(3, 5))]
    jobs = 0
    while jobs < 16:
        p, d = into[jobs] if jobs < len(into) else rng.sample(free, 2)
        if p in dock or d in dock:
            continue
        req = SubmitJob(
            header=header("t"), request_id=f"r{jobs}", reply_to="t", pickup=p, dropoff=d, mass_kg=1
        )
        assert reply_in(asked(core, "submit_job", req)).accepted
        jobs += 1
    zones = {"aisle-4": (Cell(3, 3), Cell(5, 5), 4, 70), "dock": (Cell(8, 8), Cell(9, 9), 30, None)}
    closed: set[Cell] = set()
    exempt: set[int] = set()
    pending: list[tuple[int, str, Order]] = []
    held_up: set[str] = set()
    now = 0.0
    for t in range(1500):
        now += 1.0
        for name, (first, last, closes_at, opens_at) in zones.items():
            if t == closes_at:
                closed_now = asked(core, "close_zone", closing(f"c-{name}", name, first, last), now)
                assert reply_in(closed_now).accepted
                squares = rect(first, last)
                closed |= squares
                held = {uid for _, uid, o in pending if squares & set(o.released)}
                exempt |= {
                    i
                    for u, i in ids.items()
                    if u in held or units[i].position in squares or squares & set(units[i].released)
                }
            if t == opens_at:
                assert reply_in(asked(core, "open_zone", opening(f"o-{name}", name), now)).accepted
                closed -= rect(first, last)
        for uid, order in orders_in(core.step(now)).items():
            if rng.random() < p_order:
                pending.append((t + rng.choice([0, 0, 1]), uid, order))
        due = [m for m in pending if m[0] <= t]
        pending = [m for m in pending if m[0] > t]
        for _, uid, order in due:
            yard.units[uid].on_order(order, now)
        positions = [u.position for u in units]
        problems = validate_windows(grid, positions, [u.released for u in units], MAX_WINDOW)
        assert problems == [], (t, problems)
        for u in rng.sample(units, len(units)):
            yard.tick(u.unit_id, now)
        assert (yard.world.prevented, yard.world.collisions) == (0, 0), f"at step {t}"
        waiting = {uid for _, uid, o in pending if closed & set(o.released)}
        exempt = {i for i in exempt if _still_in(units[i], closed, waiting)}
        found = validate_zones(
            [u.position for u in units], [u.released for u in units], closed, exempt
        )
        assert found == [], (t, found)
        for u in units:
            heard = rng.random() < p_state or now - (core.world.units[u.unit_id].state_at or 0) >= 3
            if heard:
                from_unit(core, "state", u.unit_id, yard.state(u.unit_id), now)
        held_up |= {j.id for j in core.jobs.jobs.values() if j.wait == "zone_closed"}
        if t > 70 and all(j.final for j in core.jobs.jobs.values()):
            return core, held_up
    raise AssertionError(
        f"jobs not finished: {[(j.id, j.state, j.wait) for j in core.jobs.jobs.values() if not j.final]}"
    )


def _still_in(unit: UnitLogic, closed: set[Cell], waiting: set[str]) -> bool:
    """Whether a unit inside a zone when it closed may still stand on or drive its squares: it
    stands on one, holds one, or has an order on its way that gives it one."""
    return unit.position in closed or bool(closed & set(unit.released)) or unit.unit_id in waiting


@pytest.mark.parametrize("window", [1, 4])
@pytest.mark.parametrize("seed", range(3))
def test_zones_closing_mid_run_keep_every_window_valid_and_every_unit_out(
    seed: int, window: int
) -> None:
    core, held_up = simulate_with_zones(seed, window, p_state=1.0, p_order=1.0)
    assert all(j.state == "done" for j in core.jobs.jobs.values())
    assert held_up  # some job's errand was in aisle-4: it waited, and was done once it opened


@pytest.mark.parametrize("seed", range(3))
def test_zones_closing_mid_run_with_late_and_lost_messages(seed: int) -> None:
    core, held_up = simulate_with_zones(seed, 4, p_state=0.6, p_order=0.7)
    assert all(j.state == "done" for j in core.jobs.jobs.values())
    assert held_up


def test_the_metrics_count_the_zones_closed_and_their_squares() -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 0)})
    metrics = CoordinatorMetrics(site.core)

    def gauges() -> tuple[float, float]:
        text = generate_latest(metrics.registry).decode()
        values = {s.name: s.value for f in text_string_to_metric_families(text) for s in f.samples}
        return values["gridfleet_zones_closed"], values["gridfleet_zone_squares_closed"]

    assert gauges() == (0.0, 0.0)
    site.close("aisle-4", Cell(3, 1), Cell(5, 4))
    site.close("aisle-5", Cell(4, 0), Cell(4, 4), "inventory")  # 4 of its 5 squares: aisle-4's
    assert gauges() == (2.0, 13.0)
    site.open("aisle-4")
    assert gauges() == (1.0, 5.0)


def test_closing_and_opening_are_audited_and_told_in_the_events() -> None:
    core = Site(OPEN_FLOOR, {"u": Cell(0, 0)}).core
    closed = asked(core, "close_zone", closing("a", "aisle-4", Cell(5, 4), Cell(3, 1)))
    refused = asked(core, "close_zone", closing("b", "aisle-4", Cell(3, 1), Cell(5, 4), "spill"))
    opened = asked(core, "open_zone", opening("c", "aisle-4"))
    entries = [e for effects in (closed, refused, opened) for e in effects.audit.entries]
    assert [(e.act, e.actor, e.target, e.detail, e.outcome, e.reason) for e in entries] == [
        ("close_zone", "op", "aisle-4 [5, 4] to [3, 1]", "cleaning", "accepted", None),
        ("close_zone", "op", "aisle-4 [3, 1] to [5, 4]", "spill", "refused", CONFLICT),
        (
            "open_zone",
            "op",
            "aisle-4",
            "zone aisle-4 opened ([3, 1] to [5, 4], closed: cleaning)",
            "accepted",
            None,
        ),
    ]
    told = [(e.kind, e.text) for effects in (closed, refused, opened) for e in effects.events]
    assert told == [
        ("zone", "zone aisle-4 closed by op: cleaning ([3, 1] to [5, 4])"),
        ("refusal", f"refused close_zone from op: {CONFLICT}"),
        ("zone", "zone aisle-4 opened by op"),
    ]
    # Each change is stored, and the view goes out with it at once.
    assert closed.zones[0][0] == "aisle-4" and opened.zones == (("aisle-4", None),)
    assert refused.zones == ()
    for effects in (closed, opened):
        assert [o.topic for o in effects.publish if o.topic.endswith("/zones")] == [
            TOPICS.fleet("zones")
        ]


@pytest.mark.parametrize(
    ("kind", "body", "why"),
    [
        (
            "close_zone",
            {"name": "aisle-4", "first": [3, 1], "last": [5, 4], "reason": ""},
            "reason",
        ),
        ("close_zone", {"name": "aisle 4", "first": [3, 1], "last": [5, 4], "reason": "x"}, "name"),
        ("close_zone", {"name": "aisle-4", "first": [3, 1], "reason": "x"}, "last"),
        (
            "close_zone",
            {"name": "a", "first": [3, 1], "last": [5, 4], "reason": "x", "why": 1},
            "why",
        ),
        ("open_zone", {"name": "../x"}, "name"),
    ],
)
def test_a_request_that_does_not_decode_is_refused_invalid_and_changes_nothing(
    kind: str, body: dict[str, object], why: str
) -> None:
    site = Site(OPEN_FLOOR, {"u": Cell(0, 0)})
    assert site.close("dock", Cell(8, 0), Cell(8, 4)).accepted
    head = {"version": "1.6", "seq": 0, "timestamp": "2026-11-21T10:00:00Z", "sender": "op"}
    payload = json.dumps({"header": head, "request_id": "bad", "reply_to": "op", **body})
    effects = site.core.on_message(TOPICS.request(kind), payload.encode(), 0.0)
    reply = reply_in(effects)
    assert (reply.accepted, reply.code) == (False, "invalid") and why in (reply.reason or "")
    assert effects.zones == () and [z.name for z in site.zones_view().zones] == ["dock"]


def test_a_stored_row_of_another_version_is_skipped(tmp_path: Path) -> None:
    store = JobStore(tmp_path / "jobs.db")
    book = ZoneBook(9, 5)
    book.close(closing("z", "aisle-4", Cell(3, 1), Cell(5, 4)), "op", FIXED)
    store.save_zones(book.take_changes())
    store._db.execute("INSERT INTO zones (name, data) VALUES ('old', '{\"shape\": 1}')")
    assert [z.name for z in store.load_zones()] == ["aisle-4"]
    store.close()


def test_with_accounts_a_zone_is_closed_by_the_account_owning_the_sender() -> None:
    accounts = default_accounts(["u"])
    core = CoordinatorCore(
        World(OPEN_FLOOR, fleet_known_after_s=0.0),
        JobBook(),
        nonce="n",
        topics=TOPICS,
        stamp=stamper("coordinator"),
        identity=Identity(accounts, vouched=True),
    )
    req = closing("z", "aisle-4", Cell(3, 1), Cell(5, 4)).model_copy(
        update={"header": header("operator-cli-9c1e")}
    )
    effects = asked(core, "close_zone", req)
    assert core.zones.zones["aisle-4"].closed_by == "operator"
    (entry,) = effects.audit.entries
    assert (entry.actor, entry.verified, entry.via) == ("operator", True, "operator-cli-9c1e")
