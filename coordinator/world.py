"""World model: the map, obstacles units reported, and the latest word of every unit.

Pure: messages and a caller-supplied time (`now`, seconds on a monotonic clock) in; queries out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gridfleet.coordinator.places import Places
from gridfleet.errors import ProtocolError
from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol import Charger, Connection, Factsheet, FleetMap, Header, Place, UnitState
from gridfleet.protocol.constants import MIN_TIMEOUT_S, STALE_AFTER_STEPS

REJOIN_SQUARES = 2  # how far from where it was last seen a unit may come back (a move under way)
# A unit's states may arrive bunched up (a busy host delays a message by up to a second, §4.4
# rule 7): the squares of that long at its pace are slack in how fast it may seem to drive, but
# never more than the fleet's loss timeout (silent longer, it is lost and rejoins, REJOIN_SQUARES).
BUNCHED_S = 1.0
CATCH_UP_SQUARES = 1  # a unit that fell behind its clock steps again at once (robots/shell.py)
# Nothing at all heard for longer than this (not even the coordinator's own status, which comes
# back to it every few seconds, pace.py) is the coordinator's own link, not its units' silence.
DEAF_AFTER_S = 10.0
# Until the retained factsheets have all arrived, "no unit could carry it" only means "none heard
# yet". They have once the coordinator hears its own status back (subscribed to last: a broker
# sends a subscription's retained messages before it handles the next one, mostly) and has the
# factsheet of every unit whose state it heard, or, should that never be (a bridge in between,
# a unit that sends none), this long after it first heard anything.
FLEET_KNOWN_AFTER_S = 5.0


@dataclass
class UnitRecord:
    """What the coordinator knows about one unit."""

    id: str
    connection: str | None = None  # online / offline / broken; None until heard
    factsheet: Factsheet | None = None
    state: UnitState | None = None
    state_at: float | None = None  # when the latest state arrived (monotonic seconds)
    lost_since: float | None = None  # when it stopped counting as active (None: active)
    fell_silent: bool = False  # lost because its states stopped, its connection still `online`
    interval_s: float | None = None  # how far apart its states arrive (moving average)
    rejoined: bool = True  # its next state may be anywhere (first, or after a connection message)
    # When its state last showed it on a new square, or it was given a job (progress.py): a unit
    # with a job standing still since longer is stuck (waits.py).
    moved_at: float | None = None
    # Squares it may still drive at once, by the fleet's clock (World.motion): what is left of
    # its slack after its latest accepted move; the time until its next state adds to it.
    allowance: float = 0.0
    job_seen_at: Cell | None = None  # where its states first showed the job_id they show now

    @property
    def position(self) -> Cell | None:
        """Where its latest state says it is."""
        return None if self.state is None else self.state.position

    @property
    def capacity_kg(self) -> float | None:
        """Its capacity from the factsheet (None until known)."""
        return None if self.factsheet is None else self.factsheet.capacity_kg


@dataclass
class World:
    """The map plus everything units told us; `grid` includes discovered obstacles."""

    base: GridMap
    step_period_s: float = 1.0
    fleet_known_after_s: float = FLEET_KNOWN_AFTER_S  # 0 where every unit is there from the start
    obstacles: set[Cell] = field(default_factory=set)
    units: dict[str, UnitRecord] = field(default_factory=dict)
    chargers: tuple[Charger, ...] = ()  # the map's chargers (protocol.md §5.2, §5.9)
    places: tuple[Place, ...] = ()  # the map's named places (protocol.md §5.10)

    def __post_init__(self) -> None:
        for c in self.chargers:
            if not self.base.is_free(c.square):
                raise ValueError(f"charger {c.name} at {list(c.square)} is off the map or a wall")
        for p in self.places:
            if not self.base.is_free(p.square):
                raise ValueError(f"place {p.name} at {list(p.square)} is off the map or a wall")
        self.named = Places(self.places)  # a job's pickup or dropoff by name (requests.py)
        self._grid = self.base.with_blocked(self.obstacles)
        self.map_id = self.base.map_id()
        self.foreign: set[str] = set()  # units whose factsheet names another map: ignored
        self.silenced: list[tuple[str, float]] = []  # (unit, seconds silent): see roll_call
        self.heard_again: list[str] = []
        self.heard_at: float | None = None  # when the coordinator last heard anything at all
        self.first_heard_at: float | None = None
        # Since when its present session is up: its own time off the broker (a failover, a
        # reconnect) is no unit's silence, which counts from here at the earliest.
        self.listening_since = float("-inf")
        self.heard_itself = False  # its own status came back: the retained factsheets are in
        # Square -> the units whose latest state is there (each state is checked against them).
        self._holders: dict[Cell, set[str]] = {}
        # Discovered obstacle -> the units whose sensors saw it and have not seen it free since:
        # a unit's `free` takes back only its own word (protocol.md §8).
        self._witnesses: dict[Cell, set[str]] = {}

    def on_foreign(self, unit_id: str, msg: Factsheet) -> bool:
        """Whether `msg` shows a unit of another map (it is then forgotten, and ignored until a
        factsheet of this map comes); True only the first time, to say so once."""
        if msg.map_id is None or msg.map_id == self.map_id:
            self.foreign.discard(unit_id)
            return False
        gone = self.units.pop(unit_id, None)
        if gone is not None and gone.position is not None:
            self._holders.get(gone.position, set()).discard(unit_id)
        first = unit_id not in self.foreign
        self.foreign.add(unit_id)
        return first

    def forget(self, unit_id: str) -> None:
        """An operator removed `unit_id` for good (protocol.md §6.11): its square, its word on
        obstacles and everything else known of it go; heard of again, it is a new unit."""
        gone = self.units.pop(unit_id, None)
        if gone is not None and gone.position is not None:
            self._holders.get(gone.position, set()).discard(unit_id)
        for witnesses in self._witnesses.values():
            witnesses.discard(unit_id)
        self.foreign.discard(unit_id)

    @property
    def grid(self) -> GridMap:
        """Static map with every discovered obstacle blocked."""
        return self._grid

    def unit(self, unit_id: str) -> UnitRecord:
        """The record of `unit_id`, created on first mention."""
        rec = self.units.get(unit_id)
        if rec is None:
            rec = self.units[unit_id] = UnitRecord(unit_id)
        return rec

    def check_square(self, c: Cell, what: str) -> None:
        """Raise ProtocolError when a square is off the map or blocked (wall or known obstacle)."""
        if not self.base.in_bounds(c):
            raise ProtocolError(
                f"{what} {list(c)} is off the {self.base.width}x{self.base.height} map"
            )
        if self.base.blocked[c.y, c.x]:
            raise ProtocolError(f"{what} {list(c)} is on a wall")
        if c in self.obstacles:
            raise ProtocolError(f"{what} {list(c)} is on a known obstacle")

    def heard(self, now: float) -> None:
        """Something arrived; after a gap of DEAF_AFTER_S, the gap does not count as units' absence.

        Cut off from the broker (a partition, a stalled link), the coordinator hears nobody and
        cannot tell who is gone: the time a lost unit has been away resumes from where it was when
        the coordinator stopped hearing, and a unit lost meanwhile counts from now.
        """
        last, self.heard_at = self.heard_at, now
        if self.first_heard_at is None:
            self.first_heard_at = now
        if last is None or now - last <= DEAF_AFTER_S:
            return
        for rec in self.units.values():
            if rec.lost_since is not None:
                rec.lost_since = now if rec.lost_since > last else rec.lost_since + (now - last)

    def listening(self, now: float) -> None:
        """The coordinator's session is up (again): units' silence counts from `now` at the
        earliest (a unit whose broker died too is not lost while back within its timeout)."""
        self.listening_since = now

    def fleet_known(self) -> bool:
        """Whether the coordinator has listened long enough to know every unit's factsheet."""
        if self.fleet_known_after_s <= 0:
            return True
        if self.first_heard_at is None or self.heard_at is None:
            return False
        if self.heard_at - self.first_heard_at >= self.fleet_known_after_s:
            return True
        # Its own status back, and no unit heard without its factsheet: that one is on its way
        # (as found on amqtt, a retained factsheet may come after the next subscription's
        # messages: a heavy job only that unit could carry was rejected just after a restart).
        return self.heard_itself and all(
            u.factsheet is not None for u in self.units.values() if u.state is not None
        )

    def away_s(self, rec: UnitRecord, now: float) -> float:
        """How long `rec` has been lost, counted while the coordinator could hear (0: active)."""
        if rec.lost_since is None:
            return 0.0
        # Until something more is heard, the time since the last message is not yet known to be
        # the unit's absence rather than the coordinator's own deafness.
        heard = now if self.heard_at is None else min(now, self.heard_at)
        return max(0.0, heard - rec.lost_since)

    def on_connection(self, unit_id: str, msg: Connection) -> None:
        """A unit said it is online, offline or broken."""
        rec = self.unit(unit_id)
        rec.connection = msg.state
        rec.rejoined = True  # (re)started: it may have been moved by hand meanwhile

    def on_factsheet(self, unit_id: str, msg: Factsheet) -> None:
        """A unit described itself."""
        self.unit(unit_id).factsheet = msg

    def on_state(
        self,
        unit_id: str,
        msg: UnitState,
        now: float,
        relocatable: bool = False,
        reach: int = 1,
        reserved: frozenset[Cell] = frozenset(),
    ) -> list[Cell]:
        """A unit's state; returns the squares whose obstacle changed (new ones, then cleared).

        The fleet judges a unit by what it can know, not by what the unit claims (protocol.md §8,
        §10). A state raises ProtocolError, and changes nothing, when
        - its square is off the map, on a wall or a known obstacle;
        - another unit still holds that square (its latest state is there, and it did not leave);
        - it jumps: further from the last state accepted than the unit's own steps between them
          allow, or faster than its wheels could have driven in the time that passed by the
          fleet's clock (`motion`: `reach` squares, its window, a step period, with a small
          slack; the unit's step counter and factsheet alone could be made up);
        - it rejoins (after a connection message, or lost) further than REJOIN_SQUARES from where
          it was last seen and not on a square released to it (`reserved`, kept for it while it
          was unheard: it may have driven them, as when the coordinator's own broker died),
          unless an operator has it out of service (`relocatable`: moved by hand);
        - it reports an obstacle that is not next to it (here, or where it was last accepted).
        A sensor reading `free` towards a discovered obstacle takes back this unit's own word: the
        obstacle is cleared once no unit that saw it still does (one unit's `free`, faulty or
        forged, never erases what another sees; an operator clears any, §6.6). A fixed obstacle
        of the map is never cleared.
        """
        self.check_square(msg.position, "position")
        rec = self.units.get(unit_id)
        self._check_square_is_free_of_others(unit_id, msg)
        allowance = None if relocatable else self._check_move(rec, msg, now, reach, reserved)
        here = msg.position
        was = None if rec is None else rec.position
        for c in msg.obstacles:
            if here.manhattan(c) != 1 and (was is None or was.manhattan(c) != 1):
                raise ProtocolError(
                    f"obstacle {list(c)} is not next to the unit (at {list(here)}): a unit "
                    "reports only what its own sensors see"
                )
        new = []
        # Besides the obstacles it reports once, every state's sensors show what is next to the
        # unit: a restarted coordinator (or one that missed the report) learns them again there.
        seen = [here.step(d) for d in Direction if getattr(msg.sensors, d.value) == "obstacle"]
        free = [here.step(d) for d in Direction if getattr(msg.sensors, d.value) == "free"]
        cleared = [c for c in free if c in self.obstacles and self._witnesses.get(c) == {unit_id}]
        for c in [*msg.obstacles, *seen]:
            if (
                self.base.in_bounds(c)
                and not self.base.blocked[c.y, c.x]
                and c not in self.obstacles
                and not self._holders.get(c)
                and c != msg.position
                and c not in new
            ):
                new.append(c)
        rec = self.unit(unit_id)
        if allowance is None:  # first heard of, rejoined or moved by hand: its slack afresh
            allowance = self.motion(rec, reach)[1]
        rec.allowance = allowance
        if rec.state is None or rec.state.job_id != msg.job_id:
            # A job's item is picked up where the state first naming it puts the unit (progress.py).
            rec.job_seen_at = None if msg.job_id is None else msg.position
        if rec.state_at is not None and not rec.rejoined:
            # A loaded broker or machine spaces states out: the loss timeout grows with them. One
            # long silence (a real loss) counts only up to the timeout it already had.
            gap = min(now - rec.state_at, self.stale_after_s(rec))
            rec.interval_s = gap if rec.interval_s is None else 0.8 * rec.interval_s + 0.2 * gap
        if rec.state is None or rec.state.position != msg.position:
            rec.moved_at = now
            if rec.position is not None:
                self._holders.get(rec.position, set()).discard(unit_id)
            self._holders.setdefault(msg.position, set()).add(unit_id)
        rec.state = msg
        rec.state_at = now
        rec.rejoined = False
        if new or cleared:
            self.obstacles.update(new)
            self.obstacles.difference_update(cleared)
            self._grid = self.base.with_blocked(self.obstacles)
        self._witnessed(unit_id, [*msg.obstacles, *seen], free, cleared)
        return [*new, *cleared]

    def _witnessed(
        self, unit_id: str, seen: list[Cell], free: list[Cell], cleared: list[Cell]
    ) -> None:
        """Note which discovered obstacles `unit_id` now sees, and which it sees free."""
        for c in free:
            self._witnesses.get(c, set()).discard(unit_id)
        for c in cleared:
            self._witnesses.pop(c, None)
        for c in seen:
            if c in self.obstacles:
                self._witnesses.setdefault(c, set()).add(unit_id)

    def clear_obstacles(self, squares: list[Cell] | None = None) -> list[Cell]:
        """An operator's word: these discovered obstacles (None: all) are gone; those cleared."""
        gone = sorted(self.obstacles if squares is None else self.obstacles & set(squares))
        if gone:
            self.obstacles.difference_update(gone)
            self._grid = self.base.with_blocked(self.obstacles)
        for c in gone:
            self._witnesses.pop(c, None)
        return gone

    def _check_square_is_free_of_others(self, unit_id: str, msg: UnitState) -> None:
        for holder in self._holders.get(msg.position, ()):
            other = self.units[holder]
            if holder != unit_id and other.connection != "offline":
                raise ProtocolError(
                    f"position {list(msg.position)} is held by unit {other.id} (its latest "
                    "state is there): two units never share a square"
                )

    def _check_move(
        self,
        rec: UnitRecord | None,
        msg: UnitState,
        now: float,
        reach: int,
        reserved: frozenset[Cell] = frozenset(),
    ) -> float | None:
        """Raise ProtocolError for a move the unit could not have made; else its allowance
        after the move (None: it starts afresh, first heard of or rejoined)."""
        if rec is None or rec.state is None or rec.state_at is None:
            return None  # first heard of (or since this coordinator started): anywhere on the map
        last = rec.state
        away = last.position.manhattan(msg.position)
        if rec.rejoined or not self.is_active(rec, now):
            if away > REJOIN_SQUARES and msg.position not in reserved | set(last.released):
                raise ProtocolError(
                    f"position {list(msg.position)} is {away} squares from {list(last.position)}, "
                    f"where unit {rec.id} was last seen: a unit rejoins where it left (an "
                    "operator takes it out of service to move it by hand)"
                )
            return None
        elapsed = max(0.0, now - rec.state_at)
        jump = (
            f"position {list(msg.position)} at step {msg.step} is {away} square"
            f"{'' if away == 1 else 's'} from {list(last.position)} at step {last.step}, the "
            f"last state accepted {elapsed:.2f} s before"
        )
        if away > max(1, msg.step - last.step):  # its own steps allow no more
            raise ProtocolError(jump)
        # Nor does the fleet's clock: what its wheels could have driven since (the unit's step
        # counter alone could be made up). Over every run of states, not just the last two:
        # squares moved <= time passed x rate + slack (the slack left is kept after each move).
        rate, slack = self.motion(rec, reach)
        allowance = rec.allowance + elapsed * rate
        if away > allowance + 1e-9:
            pace = self.pace_s(rec)
            own = "the fleet's step period" if pace == self.step_period_s else "the step period"
            own += "" if pace == self.step_period_s else " of its factsheet"
            squares = "a square" if reach == 1 else f"{reach} squares (its window)"
            raise ProtocolError(
                f"{jump}: faster than unit {rec.id} can drive (at most {allowance:.1f} "
                f"squares by now: {squares} every {pace:.2f} s, {own}, with a slack of "
                f"{round(slack, 1):g} squares)"
            )
        return min(slack, allowance - away)

    def pace_s(self, rec: UnitRecord) -> float:
        """How long a square takes the unit at least: the fleet's step period, or its
        factsheet's when that is longer (a factsheet may make a unit slower, never faster)."""
        own = rec.factsheet.step_period_s if rec.factsheet else self.step_period_s
        return max(self.step_period_s, own)

    def motion(self, rec: UnitRecord, reach: int = 1) -> tuple[float, float]:
        """(squares a second, slack in squares): how fast the fleet lets `rec` drive.

        A square each `pace_s`, or `reach` when the fleet releases it a window of that many ahead
        (a VDA 5050 vehicle drives its whole base at its own speed); the slack is one window
        driven at once, a step caught up, and the squares of the time states may arrive bunched
        up (BUNCHED_S, at most the fleet's own loss timeout) at the fleet's pace.
        """
        loss_s = max(MIN_TIMEOUT_S, STALE_AFTER_STEPS * self.step_period_s)
        bunched = min(BUNCHED_S, loss_s) / self.step_period_s
        return reach / self.pace_s(rec), reach + CATCH_UP_SQUARES + bunched

    def stale_after_s(self, rec: UnitRecord) -> float:
        """How long a unit's state may be silent before it counts as lost.

        Five periods: its declared step period, or the interval its states have been arriving
        at when that is longer (a unit that is only late is not lost; protocol.md §8).
        """
        period = rec.factsheet.step_period_s if rec.factsheet else self.step_period_s
        return max(MIN_TIMEOUT_S, STALE_AFTER_STEPS * max(period, rec.interval_s or 0.0))

    def is_active(self, rec: UnitRecord, now: float) -> bool:
        """Online (not offline/broken) with a fresh state."""
        if rec.connection in ("offline", "broken") or rec.state is None or rec.state_at is None:
            return False
        return now - max(rec.state_at, self.listening_since) <= self.stale_after_s(rec)

    def roll_call(self, now: float) -> set[str]:
        """Ids of the units heard from that are active now; notes since when each other one is lost.

        `silenced` and `heard_again` name the units that, since the last roll call, were lost
        with their connection still `online` (a link that died without a FIN: only their silence
        tells, until the broker's keep-alive ends the session), and those heard from again.
        """
        active = set()
        self.silenced, self.heard_again = [], []
        for rec in self.units.values():
            if rec.state is None:
                continue
            if self.is_active(rec, now):
                active.add(rec.id)
                if rec.fell_silent:
                    self.heard_again.append(rec.id)
                rec.lost_since, rec.fell_silent = None, False
            elif rec.lost_since is None:
                rec.lost_since = now
                if rec.connection not in ("offline", "broken") and rec.state_at is not None:
                    rec.fell_silent = True
                    self.silenced.append((rec.id, now - rec.state_at))
        return active

    def capacities(self) -> list[float]:
        """Capacities of every unit with a factsheet: what the fleet could ever carry.

        A unit that said `offline` counts too: a restarted units process says goodbye and comes
        back, and the heavy jobs only it can carry must wait for it, not be rejected.
        """
        return [u.factsheet.capacity_kg for u in self.units.values() if u.factsheet is not None]

    def carriers(self) -> list[tuple[Cell, float]]:
        """(square, capacity) of every unit with a factsheet and a known square."""
        return [
            (u.position, u.factsheet.capacity_kg)
            for u in self.units.values()
            if u.factsheet is not None and u.position is not None
        ]

    def _sorted_obstacles(self) -> list[Cell]:
        return sorted(self.obstacles, key=lambda c: (c.y, c.x))

    def fleet_map(self, header: Header) -> FleetMap:
        """The retained map view: static rows plus discovered obstacles."""
        return FleetMap(
            header=header,
            name=self.base.name,
            width=self.base.width,
            height=self.base.height,
            rows=self.base.rows(),
            obstacles=self._sorted_obstacles(),
            chargers=list(self.chargers),
            places=list(self.places),
        )
