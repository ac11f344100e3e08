"""The energy policy (protocol.md §5.9): who goes to charge, who waits for a charger, and how far a
unit may still drive, by openTCS's four thresholds.

Pure: each step the core hands in every unit's battery (its charge, its energy model, its square,
what it is doing), the chargers (chargers.py) and the distances on the map; the decisions come out
(`EnergyStep`): the charger square each unit is sent to, the units that charge standing, the jobs
to give back, how many squares each unit may still be given, and what happened (`ChargeNews`, for
the events and the history). Units that report no energy are never looked at.

The margins (the safety argument is in protocol.md §5.9): a way of n squares is predicted to cost
`need_pct(n)` = n x move_pct x MOVE_SAFETY plus standing for WAIT_FACTOR x as long as the drive and
WAIT_STEPS step periods more, at idle_pct_per_s. A job goes only to a unit that, by that prediction, still has
`critical_pct` when it reaches the charger nearest the job's dropoff; a unit goes to charge at
once when its charge is at or below its own critical level, `critical_pct` raised to cover the way
to its nearest charger (plus DETECT_MOVES: the step its state takes to tell us).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal, get_args

from gridfleet.coordinator.chargers import ChargerBook
from gridfleet.energy import ChargingSpec, thresholds_problem
from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE
from gridfleet.protocol import ChargerView, EnergyModel, EnergyView, Header, Thresholds, UnitEnergy
from gridfleet.protocol.messages import AvailableFrom, ChargeEvent, EnergyPlan

Policy = Literal["gridfleet", "naive"]
POLICIES: tuple[str, ...] = get_args(Policy)
MOVE_SAFETY = 1.25  # a square is predicted to cost a quarter more than the unit's model says
WAIT_FACTOR = 1.0  # and a unit may stand waiting as long again as it drives
# and 60 step periods more (a jam, a unit in its way, a slow pickup): counted in steps, as a
# unit's waits are, so a run faster than life (whose rates a second are faster too) is judged
# as the same run in life
WAIT_STEPS = 60
DETECT_MOVES = 1  # a unit's state tells its charge a step late: one move more to cover
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
    forced: bool = False  # an operator's `charge`: to full, no job before
    standing: bool = False  # on its charger square
    started_at: float | None = None  # when its state first said it charges
    started_pct: float = 0.0


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
        self.news: list[ChargeNews] = []
        self.heard_energy = False  # a unit reported energy: the view goes out from then on
        self.dirty = True
        self._shown: dict[str, UnitEnergy] = {}
        self.last: EnergyStep = EnergyStep()
        self._pcts: dict[str, float] = {}  # each unit's latest charge, for the waits' words
        self._models: dict[str, EnergyModel] = {}
        self._positions: dict[str, Cell] = {}
        self.started = 0  # charges started since the coordinator started (metrics)
        self.charged_s = 0.0  # seconds of the charges ended so far

    # ---- what the policy knows ---------------------------------------------------------------

    @property
    def active(self) -> bool:
        """Whether there is anything to say: chargers, or a unit that reports energy."""
        return bool(self.chargers.chargers) or self.heard_energy

    def critical_of(self, b: Battery, distance: Distance) -> float:
        """`b`'s own critical level: critical_pct, raised to cover the way to its nearest charger."""
        if self.settings.policy == "naive":
            return self.settings.critical_pct
        near = self.chargers.nearest(b.position, distance)
        if near is None:
            return self.settings.critical_pct
        return max(
            self.settings.critical_pct, need_pct(b.model, near[1] + DETECT_MOVES, self.step_s)
        )

    def charging_words(self, unit: str) -> str | None:
        """Why `unit` takes no job now because of its charge ("charging: 62 % of 80 %"), or None."""
        if unit not in self.last.unavailable:
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

    @property
    def pcts(self) -> Mapping[str, float]:
        """Each active unit's latest charge, of those that report energy."""
        return self._pcts

    def words(self, distance: Distance) -> EnergyWaits:
        """What the waits say of units without the charge for a job (waits.EnergyWords)."""
        return EnergyWaits(self, distance)

    # ---- operators ---------------------------------------------------------------------------

    def force(self, unit: str) -> None:
        """An operator's `charge`: to a charger once it carries nothing, to full, then work."""
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
        for book in (self.queued, self.stranded):
            book.pop(unit, None)
        self.forced.discard(unit)
        self._pcts.pop(unit, None)
        self.dirty = True

    # ---- the step ----------------------------------------------------------------------------

    def plan(self, batteries: Sequence[Battery], distance: Distance, now: float) -> EnergyStep:
        """This step's decisions for every unit that reports energy (see the module's words)."""
        s = self.settings
        out = EnergyStep()
        seen = {b.id for b in batteries}
        self._pcts = {b.id: b.pct for b in batteries}
        self._models = {b.id: b.model for b in batteries}
        self._positions = {b.id: b.position for b in batteries}
        if batteries:
            self.heard_energy = True
        for unit in [u for u in self.charges if u not in seen]:
            self._end(unit, 0.0, now, "it no longer reports its charge")
        self.forced &= seen
        stranded: dict[str, str] = {}
        needs: list[tuple[tuple[int, float], Battery, str, float]] = []
        for b in batteries:
            crit = self.critical_of(b, distance)
            near = self.chargers.nearest(b.position, distance)
            urgent = b.pct <= (crit if s.policy == "gridfleet" else s.critical_pct)
            charge = self.charges.get(b.id)
            if b.out_of_service or b.goal:
                if charge is not None:
                    why = "out of service" if b.out_of_service else "sent to a goal"
                    self._end(b.id, b.pct, now, why)
                continue
            if charge is not None:
                self._follow(b, charge, distance, now, out)
                continue
            if b.held:
                out.unavailable.add(b.id)
                continue
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
            else:
                self._limit(b, near is None, out)
                continue
            if near is None or (b.pct <= 0 and b.position not in self.chargers.squares):
                stranded[b.id] = (
                    f"no charger can be reached from {list(b.position)}"
                    if near is None
                    else f"battery empty at {list(b.position)}: cannot move; bring it to a charger"
                )
                self._limit(b, True, out)
                continue
            needs.append(((rank, b.pct - crit), b, why, crit))
        self.queued = {}
        for _, b, why, crit in sorted(needs, key=lambda n: (n[0], n[1].id)):
            self._send(b, why, b.pct <= crit, distance, now, out)
        if stranded != self.stranded:
            self.stranded = stranded
        for unit in stranded:
            out.unavailable.discard(unit)
        self.last = out
        return out

    def _follow(
        self, b: Battery, charge: Charge, distance: Distance, now: float, out: EnergyStep
    ) -> None:
        """A unit sent or charging: arrived, charging, full, or its charger out of reach."""
        square = self.chargers.square(charge.charger)
        if square is None or distance(b.position, square) == UNREACHABLE:
            self._end(b.id, b.pct, now, f"charger {charge.charger} cannot be reached any more")
            return
        standing = b.position == square
        if standing != charge.standing:
            charge.standing = standing
            self.dirty = True
        if standing and b.charging and charge.started_at is None:
            charge.started_at, charge.started_pct = now, b.pct
            self.started += 1
            self.news.append(ChargeNews("started", b.id, charge.charger, b.pct, charge.why))
        if standing and b.pct >= self.settings.full_pct and not b.held:
            self._end(b.id, b.pct, now, f"full ({_pct(self.settings.full_pct)})")
            self._limit(b, False, out)
            return
        out.targets[b.id] = square
        if standing:
            out.standing.add(b.id)
        if charge.forced or not standing or b.pct < charge.until_pct:
            out.unavailable.add(b.id)
        else:
            self._limit(b, False, out)  # available again: a job it can finish takes it away

    def _send(
        self, b: Battery, why: str, urgent: bool, distance: Distance, now: float, out: EnergyStep
    ) -> None:
        """To the nearest free charger; else, when critical, in place of a unit charged enough;
        else in the queue of its nearest charger."""
        s = self.settings
        forced = b.id in self.forced
        until = s.full_pct if forced else s.available_pct
        free = self.chargers.nearest(b.position, distance, free_only=True)
        if free is None and urgent and s.policy == "gridfleet":
            enough = {
                u
                for u, c in self.charges.items()
                if c.standing and not c.forced and self._pcts.get(u, 0.0) > s.sufficient_pct
            }
            taken = self.chargers.nearest(b.position, distance, held_by=enough)
            if taken is not None:
                other = self.chargers.holder(taken[0])
                if other is not None:
                    self._end(other, self._pcts.get(other, 0.0), now, f"made way for {b.id}")
                    out.targets.pop(other, None)
                    out.standing.discard(other)
                    out.unavailable.discard(other)
                free = taken
        if free is None:
            near = self.chargers.nearest(b.position, distance)
            assert near is not None  # checked by the caller
            self.queued[b.id] = near[0]
            if urgent or forced:
                out.unavailable.add(b.id)
            else:  # waiting for a charger it may still do a job it can finish
                self._limit(b, False, out)
            return
        name = free[0]
        self.chargers.take(name, b.id)
        self.forced.discard(b.id)
        self.charges[b.id] = Charge(name, why, until, forced=forced)
        self.news.append(ChargeNews("sent", b.id, name, b.pct, why))
        self.dirty = True
        square = self.chargers.square(name)
        assert square is not None
        out.targets[b.id] = square
        out.unavailable.add(b.id)
        if b.position == square:
            self.charges[b.id].standing = True
            out.standing.add(b.id)

    def _limit(self, b: Battery, stranded: bool, out: EnergyStep) -> None:
        """How far `b` may be sent on a job (the naive policy: no limit)."""
        if self.settings.policy == "naive":
            out.limits[b.id] = Limit(math.inf)
            return
        moves = max_moves(b.model, b.pct, self.settings.critical_pct, self.step_s)
        out.limits[b.id] = Limit(moves, stranded)

    def _end(self, unit: str, pct: float, now: float | None, reason: str) -> None:
        """`unit`'s charge is over (or never began): its charger is free."""
        charge = self.charges.pop(unit, None)
        if charge is None:
            return
        self.chargers.release(charge.charger, unit)
        self.dirty = True
        if charge.started_at is None:
            self.news.append(ChargeNews("cancelled", unit, charge.charger, pct, reason))
            return
        took = None if now is None else max(0.0, now - charge.started_at)
        self.charged_s += took or 0.0
        self.news.append(
            ChargeNews("ended", unit, charge.charger, pct, reason, charge.started_pct, took)
        )

    def given_jobs(self, units: Collection[str], now: float, jobs: Mapping[str, str]) -> None:
        """Units just given a job (`jobs`: unit -> job id): their charge ends, they leave."""
        for unit in units:
            if unit in self.charges:
                why = f"left for job {jobs[unit]}" if unit in jobs else "left for a job"
                self._end(unit, self._pcts.get(unit, 0.0), now, why)
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

    def short_of(self, unit: str, pickup: Cell, dropoff: Cell) -> tuple[float, float] | None:
        """(its charge, the charge the job needs) when `unit` could not finish the job."""
        p = self.policy
        limit, model = p.last.limits.get(unit), p._models.get(unit)
        here, pct = p._positions.get(unit), p._pcts.get(unit)
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
