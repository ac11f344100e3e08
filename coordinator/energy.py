"""The energy policy (protocol.md §5.9): who goes to charge, who waits for a charger, and how far a
unit may still drive, by openTCS's four thresholds.

Pure: each step the core hands in every unit's battery (its charge, its energy model, its square,
what it is doing), the squares of units that cannot make way, the chargers (chargers.py) and the
distances on the map; the decisions come out (`EnergyStep`): the charger square each unit is sent
to, the units that charge standing, the jobs to give back, how many squares each unit may still be
given, and what happened (`ChargeNews`, for the events and the history). Units that report no
energy are never looked at; a unit whose factsheet has energy but whose state has no charge yet
takes no job until it says.

The margins (the safety argument is in protocol.md §5.9): a way of n squares is predicted to cost
`need_pct(n)` = n x move_pct x MOVE_SAFETY plus standing for WAIT_FACTOR x as long as the drive and
WAIT_STEPS step periods more, at idle_pct_per_s. A job goes only to a unit that, by that prediction, still has
`critical_pct` when it reaches the charger nearest the job's dropoff; a unit goes to charge at
once when its charge is at or below its own critical level, `critical_pct` raised to cover the way
to its nearest charger with the lag of its state (`to_charger_pct`: DETECT_MOVES more moves and
DETECT_PCT more). It is sent only to a charger whose way its charge covers: the nearest, or one
farther that it still reaches with `critical_pct` (`reach`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal, get_args

from gridfleet.coordinator.chargers import ChargerBook
from gridfleet.energy import ChargingSpec, thresholds_problem
from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE
from gridfleet.protocol import ChargerView, EnergyModel, EnergyView, Header, Thresholds, UnitEnergy
from gridfleet.protocol.constants import STATE_HEARTBEAT_STEPS
from gridfleet.protocol.messages import AvailableFrom, ChargeEvent, EnergyPlan

Policy = Literal["gridfleet", "naive"]
POLICIES: tuple[str, ...] = get_args(Policy)
MOVE_SAFETY = 1.25  # a square is predicted to cost a quarter more than the unit's model says
WAIT_FACTOR = 1.0  # and a unit may stand waiting as long again as it drives
# and 60 step periods more (a jam, a unit in its way, a slow pickup): counted in steps, as a
# unit's waits are, so a run faster than life (whose rates a second are faster too) is judged
# as the same run in life
WAIT_STEPS = 60
# A unit's state tells its charge late: a moving unit sends one each move, but a standing one only
# when its whole percent changes or on the heartbeat (STATE_HEARTBEAT_STEPS steps), and it is read a
# step later. So its charge may be up to a heartbeat's moves and a whole percent below what it said.
DETECT_MOVES = STATE_HEARTBEAT_STEPS
DETECT_PCT = 1.0
# A unit standing on its charger that does not say it charges (a charger that failed, a vehicle that
# ended its charge itself) holds it this many steps, and at least this long, then its charge ends.
CHARGE_START_STEPS = 20
CHARGE_START_MIN_S = 30.0
# Allocation prefers the unit with more charge among near-equal ways: each % of charge a unit has
# less counts as this many squares more of travel (0 % to 100 %: five squares).
CHARGE_PREFERENCE = 0.05
Distance = Callable[[Cell, Cell], int]


@dataclass(frozen=True)
class EnergySettings:
    """The thresholds (% of a full charge) and which policy applies them."""

    critical_pct: float = 20.0  # at or below: no job, to a charger at once
    good_pct: float = 50.0  # below, idle: to a charger
    sufficient_pct: float = 80.0  # a charging unit takes jobs again from here
    full_pct: float = 95.0  # a charging unit with nothing to do charges up to here
    available_from: AvailableFrom = "sufficient"  # or "full"
    # "naive", the benchmark's baseline: to the nearest charger only at critical_pct, no check
    # that a job can be finished, charged to full_pct before it works again.
    policy: Policy = "gridfleet"

    @classmethod
    def of(cls, spec: ChargingSpec, policy: str = "gridfleet") -> EnergySettings:
        """A scenario's [charging] under `policy` (not checked: see `problem`)."""
        return cls(
            spec.critical_pct,
            spec.good_pct,
            spec.sufficient_pct,
            spec.full_pct,
            spec.available_from,  # type: ignore[arg-type]  # checked by `problem`
            policy,  # type: ignore[arg-type]
        )

    def problem(self) -> str | None:
        """Why these settings cannot work, in one line; None when they can."""
        for name in ("critical_pct", "good_pct", "sufficient_pct", "full_pct"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not 0 <= value <= 100:
                return f"{name} must be a number from 0 to 100 (% of a full charge), got {value!r}"
        if self.available_from not in ("sufficient", "full"):
            return f'available_from must be "sufficient" or "full", got {self.available_from!r}'
        if self.policy not in POLICIES:
            return f"energy policy must be one of {', '.join(POLICIES)}, got {self.policy!r}"
        spec = ChargingSpec(
            self.critical_pct,
            self.good_pct,
            self.sufficient_pct,
            self.full_pct,
            self.available_from,
        )
        return thresholds_problem(spec)

    @property
    def available_pct(self) -> float:
        """From what charge a charging unit takes jobs again."""
        if self.available_from == "full" or self.policy == "naive":
            return self.full_pct
        return self.sufficient_pct

    def thresholds(self) -> Thresholds:
        """As the energy view shows them."""
        return Thresholds(
            critical_pct=self.critical_pct,
            good_pct=self.good_pct,
            sufficient_pct=self.sufficient_pct,
            full_pct=self.full_pct,
            available_from="full" if self.policy == "naive" else self.available_from,
        )


def need_pct(model: EnergyModel, moves: float, step_s: float) -> float:
    """The charge a way of `moves` squares is predicted to cost, with the margins."""
    drive = moves * model.move_pct * MOVE_SAFETY
    return drive + model.idle_pct_per_s * step_s * (moves * WAIT_FACTOR + WAIT_STEPS)


def max_moves(model: EnergyModel, pct: float, floor: float, step_s: float) -> float:
    """The most squares a unit with `pct` may drive and still keep `floor` (-1: not one)."""
    per = model.move_pct * MOVE_SAFETY + model.idle_pct_per_s * step_s * WAIT_FACTOR
    spare = pct - floor - model.idle_pct_per_s * step_s * WAIT_STEPS
    if spare < 0:
        return -1.0
    return math.inf if per == 0 else spare / per


def to_charger_pct(model: EnergyModel, moves: float, step_s: float) -> float:
    """The charge a unit needs to reach a charger `moves` squares off, as its state tells it:
    the way with the margins, DETECT_MOVES more of it and DETECT_PCT more (its state's lag)."""
    return need_pct(model, moves + DETECT_MOVES, step_s) + DETECT_PCT


@dataclass(frozen=True)
class Battery:
    """One unit that reports energy, as the policy sees it this step."""

    id: str
    position: Cell
    pct: float
    model: EnergyModel
    charging: bool = False  # its state says it charges
    free: bool = True  # no job, goal or control: coordinated, heard, not stopped
    job: bool = False  # a job it has not picked up yet
    carrying: bool = False  # an item on board (or one to put back)
    held: bool = False  # paused by an operator: it keeps its charge, and drives nowhere
    goal: bool = False  # sent to a goal by an operator: the operator's word wins
    out_of_service: bool = False  # taken out of service: no charge


@dataclass(frozen=True)
class Limit:
    """How far a unit may be sent on a job: squares, and whether no charger can be reached."""

    moves: float  # unit -> pickup -> dropoff -> nearest charger, at most
    stranded: bool = False  # no charger: the way ends at the dropoff


@dataclass(frozen=True)
class ChargeNews:
    """Something the policy did: for the events, the history and the metrics."""

    event: Literal["sent", ChargeEvent, "cancelled"]
    unit: str
    charger: str
    pct: float
    reason: str
    from_pct: float | None = None  # (ended) its charge when it started
    seconds: float | None = None  # (ended) how long it charged


@dataclass
class Charge:
    """A unit sent to a charger, or charging on it."""

    charger: str
    why: str  # in words, e.g. "below good 50 %"
    until_pct: float  # it takes jobs again from here (full: `forced` or naive)
    pct: float  # its latest charge (what its end says, should it be lost on the way)
    forced: bool = False  # an operator's `charge`: to full, no job before
    standing: bool = False  # on its charger square
    started_at: float | None = None  # when its state first said it charges
    started_pct: float = 0.0
    idle_steps: int = 0  # steps in a row on its charger without charging
    idle_since: float | None = None  # since when


@dataclass
class EnergyStep:
    """What the policy decided this step."""

    targets: dict[str, Cell] = field(default_factory=dict)  # unit -> its charger square
    standing: set[str] = field(default_factory=set)  # charging on it: the planner goes round
    unavailable: set[str] = field(default_factory=set)  # no job for them now
    limits: dict[str, Limit] = field(default_factory=dict)  # the others with energy
    requeue: dict[str, str] = field(default_factory=dict)  # unit -> why its job goes back


def _pct(value: float) -> str:
    return f"{value:.0f} %"


# A candidate for a charger: (urgency, the unit, why, urgent, its nearest charger).
_Need = tuple[tuple[int, float], Battery, str, bool, tuple[str, int]]


class EnergyPolicy:
    """The charges under way, the queue, the stranded units, and what the view shows."""

    def __init__(self, settings: EnergySettings, chargers: ChargerBook, step_s: float) -> None:
        self.settings = settings
        self.chargers = chargers
        self.step_s = step_s
        self.charges: dict[str, Charge] = {}  # unit -> its charge (sent or charging)
        self.queued: dict[str, str] = {}  # unit -> the charger it waits for, most urgent first
        self.stranded: dict[str, str] = {}  # unit -> why no charger can help
        self.forced: set[str] = set()  # an operator's `charge` not under way yet
        self.refused: dict[str, set[str]] = {}  # unit -> the chargers that did not charge it
        # Units a waiting job needs more charge of (the last waits', waits.py): unit -> the %.
        self.wanted: dict[str, float] = {}
        self._wanting: dict[str, float] = {}  # this step's: a charge for one goes up to its %
        self.news: list[ChargeNews] = []
        self.heard_energy = False  # a unit reported energy: the view goes out from then on
        self.dirty = True
        self._shown: dict[str, UnitEnergy] = {}
        self.last: EnergyStep = EnergyStep()
        self._pcts: dict[str, float] = {}  # each unit's latest charge, for the waits' words
        self._models: dict[str, EnergyModel] = {}
        self._positions: dict[str, Cell] = {}
        self._unknown: set[str] = set()  # energy in its factsheet, no charge in its state yet
        self._blocked: Mapping[Cell, str] = {}  # squares of units that cannot make way
        self._now = 0.0  # the latest step's time
        self.started = 0  # charges started since the coordinator started (metrics)
        self._ended_s = 0.0  # seconds of the charges ended so far

    # ---- what the policy knows ---------------------------------------------------------------

    @property
    def active(self) -> bool:
        """Whether there is anything to say: chargers, or a unit that reports energy."""
        return bool(self.chargers.chargers) or self.heard_energy

    @property
    def pcts(self) -> Mapping[str, float]:
        """Each active unit's latest charge, of those that report energy."""
        return MappingProxyType(self._pcts)

    @property
    def models(self) -> Mapping[str, EnergyModel]:
        """Each active unit's energy model, of those that report energy."""
        return MappingProxyType(self._models)

    @property
    def positions(self) -> Mapping[str, Cell]:
        """Each active unit's square, of those that report energy."""
        return MappingProxyType(self._positions)

    @property
    def charged_s(self) -> float:
        """Seconds units charged since the coordinator started: the charges ended and those
        under way (up to the latest step)."""
        running = sum(
            max(0.0, self._now - c.started_at)
            for c in self.charges.values()
            if c.started_at is not None
        )
        return self._ended_s + running

    def charging_words(self, unit: str) -> str | None:
        """Why `unit` takes no job now because of its charge ("charging: 62 % of 80 %"), or None."""
        if unit not in self.last.unavailable or unit in self._unknown:
            return None
        pct = self._pcts.get(unit)
        charge = self.charges.get(unit)
        if pct is None:
            return None
        if charge is not None and charge.standing:
            return f"charging: {_pct(pct)} of {_pct(charge.until_pct)}"
        if charge is not None:
            return f"on its way to charge at {charge.charger} ({_pct(pct)})"
        return f"battery critical: {_pct(pct)}, waiting for a charger"

    def unknown_words(self, unit: str) -> str | None:
        """Why `unit`, whose factsheet has energy, takes no job: its charge is not known yet."""
        if unit in self._unknown:
            return "its charge is not known: its state reports none"
        return None

    def cannot_charge(
        self, unit: str, position: Cell, pct: float, distance: Distance
    ) -> str | None:
        """Why `unit` on `position` with `pct` could not be sent to charge, in words (as its
        stranded plan says); None when it could. The chargers that did not charge it count:
        an operator's `charge` tries them again (`force`)."""
        blocked = self._blocked
        near = self.chargers.nearest(position, distance, blocked=blocked, unit=unit)
        if near is not None and (pct > 0 or near[1] == 0):
            return None
        return self._stranded_words(unit, position, near, distance, blocked, ())

    def words(self, distance: Distance) -> EnergyWaits:
        """What the waits say of units without the charge for a job (waits.EnergyWords)."""
        return EnergyWaits(self, distance)

    # ---- operators ---------------------------------------------------------------------------

    def force(self, unit: str) -> None:
        """An operator's `charge`: to a charger once it carries nothing, to full, then work (a
        unit not heard this step goes once it is); the chargers that did not charge it are
        tried again."""
        self.refused.pop(unit, None)
        charge = self.charges.get(unit)
        if charge is not None:  # charging already (or on its way): to full now
            charge.forced, charge.until_pct = True, self.settings.full_pct
            charge.why = "an operator asked it to charge"
        else:
            self.forced.add(unit)
        self.dirty = True

    def forget(self, unit: str) -> None:
        """A removed unit: no charge, no queue, no charger held for it."""
        charge = self.charges.pop(unit, None)
        if charge is not None:
            self.chargers.release(charge.charger, unit)
        for book in (self.queued, self.stranded, self.refused):
            book.pop(unit, None)
        self.forced.discard(unit)
        self._unknown.discard(unit)
        self._pcts.pop(unit, None)
        self.dirty = True

    # ---- the step ----------------------------------------------------------------------------

    def plan(
        self,
        batteries: Sequence[Battery],
        distance: Distance,
        now: float,
        blocked: Mapping[Cell, str] | None = None,
        unknown: Collection[str] = (),
    ) -> EnergyStep:
        """This step's decisions for every unit that reports energy (see the module's words).

        `blocked`: the squares of units that cannot make way (lost, paused, stopped, out of
        service, empty): a charger there is given to no other unit. `unknown`: units whose
        factsheet has energy but whose state has no charge yet: no job for them.
        """
        s = self.settings
        out = EnergyStep()
        blocked = {} if blocked is None else blocked
        by_id = {b.id: b for b in batteries}
        self._now, self._blocked = now, blocked
        self._pcts = {b.id: b.pct for b in batteries}
        self._models = {b.id: b.model for b in batteries}
        self._positions = {b.id: b.position for b in batteries}
        self._unknown = set(unknown) - by_id.keys()
        out.unavailable |= self._unknown
        if batteries or self._unknown:
            self.heard_energy = True
        for unit in [u for u in self.charges if u not in by_id]:
            self._end(unit, self.charges[unit].pct, now, "it no longer reports its charge")
        self._occupied(batteries, blocked, now)
        stranded: dict[str, str] = {}
        needs: list[_Need] = []
        wanted, self.wanted = self.wanted, {}  # told by the last step's waits, told again
        self._wanting = wanted
        for b in batteries:
            charge = self.charges.get(b.id)
            if b.out_of_service or b.goal:
                if charge is not None:
                    why = "out of service" if b.out_of_service else "sent to a goal"
                    self._end(b.id, b.pct, now, why)
                self._limit(b, False, out)  # (allocation gives such a unit no job anyway)
                continue
            if charge is not None and self._follow(b, charge, distance, now, out):
                continue
            if b.held:
                out.unavailable.add(b.id)
                continue
            near = self._nearest(b.id, b.position, distance, blocked)
            crit = self._critical(b, near)
            urgent = b.pct <= crit
            if b.job and (urgent or b.id in self.forced) and s.policy == "gridfleet":
                why = (
                    "an operator asked it to charge"
                    if b.id in self.forced
                    else (f"battery critical ({_pct(b.pct)})")
                )
                out.requeue[b.id] = f"unit {b.id} sent to charge: {why}"
            elif not b.free or b.carrying or b.job:
                self._limit(b, near is None, out)
                continue
            if b.id in self.forced:
                why, rank = "an operator asked it to charge", 0
            elif urgent:
                why, rank = f"at or below its critical level {_pct(crit)}", 0
            elif s.policy == "gridfleet" and b.pct < s.good_pct:
                why, rank = f"below good {_pct(s.good_pct)}", 1
            elif s.policy == "gridfleet" and b.id in wanted:
                # Idle above good, but a job waits that it alone could do with more charge: it
                # would idle down to good first, and the job with it (a playfield run took
                # 1,670 steps, not 300, that way).
                why, rank = f"a job waits for it to have {_pct(wanted[b.id])}", 2
            else:
                self._limit(b, near is None, out)
                continue
            if near is None or (b.pct <= 0 and near[1] > 0):
                refused = self.refused.get(b.id, set())
                words = self._stranded_words(b.id, b.position, near, distance, blocked, refused)
                stranded[b.id] = words
                self._limit(b, True, out)
                continue
            needs.append(((rank, b.pct - crit), b, why, urgent, near))
        self.queued = {}
        for _, b, why, urgent, near in sorted(needs, key=lambda n: (n[0], n[1].id)):
            self._send(b, why, urgent, near, distance, now, out, by_id)
        self.stranded = stranded
        for unit in stranded:
            out.unavailable.discard(unit)
        self.last = out
        return out

    def _nearest(
        self, unit: str, square: Cell, distance: Distance, blocked: Mapping[Cell, str]
    ) -> tuple[str, int] | None:
        """The nearest charger `unit` may use from `square`: reachable, not one that did not
        charge it, not one a unit that cannot make way stands on."""
        skip = self.refused.get(unit, set())
        return self.chargers.nearest(square, distance, skip=skip, blocked=blocked, unit=unit)

    def _critical(self, b: Battery, near: tuple[str, int] | None) -> float:
        """`b`'s own critical level: critical_pct, raised to cover the way to its nearest
        charger `near` with its state's lag."""
        if self.settings.policy == "naive" or near is None:
            return self.settings.critical_pct
        return max(self.settings.critical_pct, to_charger_pct(b.model, near[1], self.step_s))

    def _reach(self, b: Battery, near: tuple[str, int]) -> float | None:
        """The farthest charger, in squares, `b` may be sent to (None: any): one whose way its
        charge covers with critical_pct left, or one as near as its nearest, `near`."""
        if self.settings.policy == "naive":
            return None
        model = b.model
        allowance = max(
            b.pct - self.settings.critical_pct, to_charger_pct(model, near[1], self.step_s)
        )
        per = model.move_pct * MOVE_SAFETY + model.idle_pct_per_s * self.step_s * WAIT_FACTOR
        if per == 0:
            return None
        fixed = model.idle_pct_per_s * self.step_s * WAIT_STEPS + DETECT_PCT
        return (allowance - fixed) / per - DETECT_MOVES + 1e-9

    def _stranded_words(
        self,
        unit: str,
        square: Cell,
        near: tuple[str, int] | None,
        distance: Distance,
        blocked: Mapping[Cell, str],
        refused: Collection[str],
    ) -> str:
        """Why no charger can help `unit` on `square` (`near`: the nearest it may use; `refused`:
        those that did not charge it), in words."""
        here = list(square)
        if near is not None:
            return f"battery empty at {here}: cannot move; bring it to a charger"
        if not self.chargers.chargers:
            return "the map has no chargers: add [[chargers]] to the scenario"
        reachable = [
            c
            for c in self.chargers.chargers
            if c.name not in refused and distance(square, c.square) != UNREACHABLE
        ]
        taken = [
            f"{c.name} is taken by {blocked[c.square]}, which cannot make way"
            for c in reachable
            if blocked.get(c.square) not in (None, unit)
        ]
        if refused:
            names = ", ".join(sorted(refused))
            which = f"charger {names} does" if len(refused) == 1 else f"chargers {names} do"
            rest = f"; {'; '.join(taken)}" if taken else ""
            return f"{which} not charge it; no other charger can be reached from {here}{rest}"
        if taken:
            return f"no charger is free to reach from {here}: {'; '.join(taken)}"
        return f"no charger can be reached from {here}"

    def _occupied(
        self, batteries: Sequence[Battery], blocked: Mapping[Cell, str], now: float
    ) -> None:
        """Chargers a unit stands on and keeps: one that charges there (and holds no charge of
        ours: after a restart) is given it, before any unit is sent anywhere; a unit sent to a
        charger another unit charges on, or one that cannot make way stands on, goes elsewhere."""
        on = {b.position: b for b in batteries}
        for c in self.chargers.chargers:
            holder = self.chargers.holder(c.name)
            b = on.get(c.square)
            adopt = (
                b is not None
                and b.charging
                and b.id not in self.charges
                and not (b.job or b.carrying or b.goal or b.out_of_service)
            )
            occupant = b.id if adopt and b is not None else blocked.get(c.square)
            if occupant is None or occupant == holder:
                continue
            if holder is not None:
                how = "charges there" if adopt else "cannot make way"
                why = f"charger {c.name} is taken: {occupant} stands on it and {how}"
                self._end(holder, self.charges[holder].pct, now, why)
            if adopt and b is not None:
                forced = b.id in self.forced
                self.forced.discard(b.id)
                until = self.settings.full_pct if forced else self.settings.available_pct
                why = "an operator asked it to charge" if forced else "found charging there"
                self.chargers.take(c.name, b.id)
                self.charges[b.id] = Charge(
                    c.name,
                    why,
                    until,
                    b.pct,
                    forced=forced,
                    standing=True,
                    started_at=now,
                    started_pct=b.pct,
                )
                self.started += 1
                self.news.append(ChargeNews("started", b.id, c.name, b.pct, why))
                self.dirty = True

    def _follow(
        self, b: Battery, charge: Charge, distance: Distance, now: float, out: EnergyStep
    ) -> bool:
        """A unit sent or charging: arrived, charging, full, or its charge over. False when its
        charge ended: the unit is planned as any other this step."""
        charge.pct = b.pct
        name = charge.charger
        square = self.chargers.square(name)
        if square is None or distance(b.position, square) == UNREACHABLE:
            self._end(b.id, b.pct, now, f"charger {name} cannot be reached any more")
            return False
        standing = b.position == square
        if b.pct <= 0 and not standing:
            self._end(b.id, b.pct, now, f"battery empty on its way to {name}")
            return False
        if standing != charge.standing:
            charge.standing = standing
            self.dirty = True
        if standing and b.charging:
            charge.idle_steps, charge.idle_since = 0, None
            self.refused.pop(b.id, None)
            if charge.started_at is None:
                charge.started_at, charge.started_pct = now, b.pct
                self.started += 1
                self.news.append(ChargeNews("started", b.id, name, b.pct, charge.why))
        elif standing and not b.held:  # on its charger, not charging: for a while at most
            charge.idle_steps += 1
            charge.idle_since = now if charge.idle_since is None else charge.idle_since
            if (
                charge.idle_steps > CHARGE_START_STEPS
                and now - charge.idle_since >= CHARGE_START_MIN_S
            ):
                if charge.started_at is None:
                    self.refused.setdefault(b.id, set()).add(name)
                    why = f"charger {name} does not charge it"
                else:
                    why = f"it stopped charging by itself at {_pct(b.pct)}"
                self._end(b.id, b.pct, now, why)
                return False
        else:
            charge.idle_steps, charge.idle_since = 0, None
        if standing and b.pct >= self.settings.full_pct and not b.held:
            self._end(b.id, b.pct, now, f"full ({_pct(self.settings.full_pct)})")
            return False
        out.targets[b.id] = square
        if standing:
            out.standing.add(b.id)
        if charge.forced or not standing or b.pct < charge.until_pct:
            out.unavailable.add(b.id)
        else:
            self._limit(b, False, out)  # available again: a job it can finish takes it away
        return True

    def _send(
        self,
        b: Battery,
        why: str,
        urgent: bool,
        near: tuple[str, int],
        distance: Distance,
        now: float,
        out: EnergyStep,
        by_id: Mapping[str, Battery],
    ) -> None:
        """To the nearest free charger its charge reaches (`_reach`); else, when critical, in
        place of a unit charged enough; else in the queue of its nearest charger `near`."""
        s = self.settings
        forced = b.id in self.forced
        until = s.full_pct if forced else s.available_pct
        if b.id in self._wanting:  # enough for the job that waits for it, with a point spare
            until = max(until, min(s.full_pct, self._wanting[b.id] + 1.0))
        reach = self._reach(b, near)
        skip = self.refused.get(b.id, set())
        free = self.chargers.nearest(
            b.position,
            distance,
            free_only=True,
            within=reach,
            skip=skip,
            blocked=self._blocked,
            unit=b.id,
        )
        if free is None and urgent and s.policy == "gridfleet":
            enough = {
                u
                for u, c in self.charges.items()
                if c.standing
                and not c.forced
                and u in by_id
                and by_id[u].pct > s.sufficient_pct
                and by_id[u].position not in self._blocked  # paused, stopped: it cannot leave
            }
            taken = self.chargers.nearest(
                b.position, distance, held_by=enough, within=reach, skip=skip
            )
            if taken is not None:
                other = self.chargers.holder(taken[0])
                if other is not None:
                    self._end(other, by_id[other].pct, now, f"made way for {b.id}")
                    out.targets.pop(other, None)
                    out.standing.discard(other)
                    out.unavailable.discard(other)
                    self._limit(by_id[other], False, out)
                free = taken
        if free is None:
            self.queued[b.id] = near[0]
            if urgent or forced:
                out.unavailable.add(b.id)
            else:  # waiting for a charger it may still do a job it can finish
                self._limit(b, False, out)
            return
        name = free[0]
        self.chargers.take(name, b.id)
        self.forced.discard(b.id)
        self.charges[b.id] = Charge(name, why, until, b.pct, forced=forced)
        self.news.append(ChargeNews("sent", b.id, name, b.pct, why))
        self.dirty = True
        square = self.chargers.square(name)
        assert square is not None
        out.targets[b.id] = square
        out.unavailable.add(b.id)
        out.limits.pop(b.id, None)
        if b.position == square:
            self.charges[b.id].standing = True
            out.standing.add(b.id)

    def _limit(self, b: Battery, stranded: bool, out: EnergyStep) -> None:
        """How far `b` may be sent on a job (the naive policy: no limit)."""
        out.unavailable.discard(b.id)
        if self.settings.policy == "naive":
            out.limits[b.id] = Limit(math.inf)
            return
        moves = max_moves(b.model, b.pct, self.settings.critical_pct, self.step_s)
        out.limits[b.id] = Limit(moves, stranded)

    def _end(self, unit: str, pct: float, now: float, reason: str) -> None:
        """`unit`'s charge is over (or never began): its charger is free."""
        charge = self.charges.pop(unit, None)
        if charge is None:
            return
        self.chargers.release(charge.charger, unit)
        self.dirty = True
        if charge.started_at is None:
            self.news.append(ChargeNews("cancelled", unit, charge.charger, pct, reason))
            return
        took = max(0.0, now - charge.started_at)
        self._ended_s += took
        self.news.append(
            ChargeNews("ended", unit, charge.charger, pct, reason, charge.started_pct, took)
        )

    def given_jobs(self, jobs: Mapping[str, str], now: float) -> None:
        """Units just given a job (`jobs`: unit -> job id): their charge ends, they leave."""
        for unit, job_id in jobs.items():
            charge = self.charges.get(unit)
            if charge is not None:
                self._end(unit, charge.pct, now, f"left for job {job_id}")
                self.last.targets.pop(unit, None)
                self.last.standing.discard(unit)
            if self.queued.pop(unit, None) is not None:
                self.dirty = True

    def take_news(self) -> list[ChargeNews]:
        """What happened since the last call (it counts as told from here)."""
        news, self.news = self.news, []
        return news

    # ---- the view ----------------------------------------------------------------------------

    def units_view(self) -> dict[str, UnitEnergy]:
        """The units the policy moves, holds, queues or cannot help, in words that change only
        with their plans (never with each % of charge)."""
        out: dict[str, UnitEnergy] = {}
        for unit, c in sorted(self.charges.items()):
            plan: EnergyPlan = "charging" if c.standing else "to_charger"
            words = f"{c.why}; charges up to {_pct(c.until_pct)}"
            out[unit] = UnitEnergy(plan=plan, charger=c.charger, reason=words)
        for unit, name in self.queued.items():
            out[unit] = UnitEnergy(
                plan="queued", charger=name, reason=f"waiting for charger {name}: every one is busy"
            )
        for unit, why in sorted(self.stranded.items()):
            out[unit] = UnitEnergy(plan="stranded", reason=why)
        return out

    def changed(self) -> bool:
        """Whether the view differs from the last one taken."""
        return self.dirty or self.units_view() != self._shown

    def view(self, header: Header) -> EnergyView:
        """The energy view, which counts as sent from here on."""
        units = self.units_view()
        self._shown, self.dirty = units, False
        queues: dict[str, list[str]] = {}
        for unit, name in self.queued.items():
            queues.setdefault(name, []).append(unit)
        chargers = [
            ChargerView(
                name=c.name,
                square=c.square,
                unit=self.chargers.holder(c.name),
                queue=queues.get(c.name, []),
            )
            for c in self.chargers.chargers
        ]
        return EnergyView(
            header=header, thresholds=self.settings.thresholds(), chargers=chargers, units=units
        )


@dataclass(frozen=True)
class EnergyWaits:
    """The policy's words for the waits (waits.EnergyWords), with the map's distances."""

    policy: EnergyPolicy
    distance: Distance

    def charging_words(self, unit: str) -> str | None:
        """Why `unit` takes no job now for its charge, or None."""
        return self.policy.charging_words(unit)

    def unknown_words(self, unit: str) -> str | None:
        """Why `unit` takes no job while its charge is not known, or None."""
        return self.policy.unknown_words(unit)

    def wanted(self, unit: str, needs_pct: float) -> None:
        """A job waits for `unit` to have `needs_pct` (its charge to reach it: `plan`)."""
        if needs_pct > self.policy.settings.full_pct:
            return  # more than a charge gives: no charge would let it do the job
        wanted = self.policy.wanted
        wanted[unit] = min(wanted.get(unit, needs_pct), needs_pct)

    def short_of(self, unit: str, pickup: Cell, dropoff: Cell) -> tuple[float, float] | None:
        """(its charge, the charge the job needs) when `unit` could not finish the job."""
        p = self.policy
        limit, model = p.last.limits.get(unit), p.models.get(unit)
        here, pct = p.positions.get(unit), p.pcts.get(unit)
        if limit is None or model is None or here is None or pct is None:
            return None
        legs = [self.distance(here, pickup), self.distance(dropoff, pickup)]
        near = p.chargers.nearest(dropoff, self.distance)
        if near is not None:
            legs.append(near[1])
        elif not limit.stranded:
            return None  # no charger after it at all: the job's reach says so, not the battery
        if any(d == UNREACHABLE for d in legs):
            return None
        moves = float(sum(legs))
        if moves <= limit.moves:
            return None
        return pct, p.settings.critical_pct + need_pct(model, moves, p.step_s)
