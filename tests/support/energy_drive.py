"""Drive the coordinator core's energy policy: units with a battery of a fixed model on a small
open map with two chargers, their states and the operators' requests (tests/coordinator).

The energy model of every unit here: a move costs 5 %, standing costs nothing, so a way of n
squares is predicted to cost 6.25 x n % (MOVE_SAFETY 1.25); the way to a charger n squares off
needs 6.25 x (n + 3) + 1 % (DETECT_MOVES 3, DETECT_PCT 1: the lag of a unit's state).
"""

from __future__ import annotations

from typing import Any

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.effects import Effects
from gridfleet.coordinator.energy import EnergySettings
from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.world import World
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import (
    Charger,
    Connection,
    ControlUnit,
    EnergyModel,
    Factsheet,
    Leds,
    Sensors,
    SubmitJob,
    UnitState,
)

from support.coordinator_drive import TOPICS, from_unit, request
from support.effects import header, published, stamper

OPEN = GridMap.from_rows(["......", "......"])
C1, C2 = Charger(name="C1", square=Cell(0, 0)), Charger(name="C2", square=Cell(5, 0))
MODEL = EnergyModel(move_pct=5.0, idle_pct_per_s=0.0, charge_pct_per_s=5.0)
ENERGY = "gridfleet/v1/fleet/energy"
THRESHOLDS = {
    "critical_pct": 20.0,
    "good_pct": 50.0,
    "sufficient_pct": 80.0,
    "full_pct": 95.0,
    "available_from": "sufficient",
}


def make(
    chargers: tuple[Charger, ...] = (C1, C2),
    grid: GridMap = OPEN,
    settings: EnergySettings | None = None,
) -> CoordinatorCore:
    """A core on `grid` with `chargers`, every header at FIXED."""
    return CoordinatorCore(
        World(grid, step_period_s=1.0, fleet_known_after_s=0.0, chargers=chargers),
        JobBook(),
        nonce="n",
        topics=TOPICS,
        stamp=stamper("coordinator"),
        energy=settings,
    )


def acked(core: CoordinatorCore, unit: str) -> dict[str, Any]:
    """The fields of a state that acknowledge the latest order `unit` was sent."""
    track = core.orders.tracks[unit]
    return {"order_id": track.order_id, "order_update_id": track.update_id}


def state(unit: str, at: Cell, pct: float | None, seq: int = 0, **over: Any) -> UnitState:
    """`unit` idle on `at` with `pct` % of charge (None: it reports no energy)."""
    msg = UnitState(
        header=header(unit, seq),
        step=seq,
        position=at,
        direction="-",
        status="idle",
        leds=Leds(),
        sensors=Sensors(N="free", E="free", S="free", W="free"),
        battery_pct=pct,
    )
    return msg.model_copy(update=over)


def meet(core: CoordinatorCore, unit: str, at: Cell, pct: float | None) -> None:
    """`unit` comes online on `at` with `pct` % (and the energy model when it reports energy)."""
    from_unit(core, "connection", unit, Connection(header=header(unit), state="online"), 0.0)
    energy = None if pct is None else MODEL
    fs = Factsheet(header=header(unit), capacity_kg=5.0, step_period_s=1.0, energy=energy)
    from_unit(core, "factsheet", unit, fs, 0.0)
    from_unit(core, "state", unit, state(unit, at, pct), 0.0)


def submit(
    core: CoordinatorCore, pickup: Cell, dropoff: Cell, job_id: str = "j1", now: float = 0.0
) -> Any:
    """A job from `pickup` to `dropoff` submitted by "op"; its reply's (accepted, reason)."""
    req = SubmitJob(
        header=header("op"),
        request_id=f"r-{job_id}",
        reply_to="op",
        pickup=pickup,
        dropoff=dropoff,
        mass_kg=1.0,
        job_id=job_id,
    )
    effects = request(core, "submit_job", req, now)
    (reply,) = [p for t, p, *_ in published(effects) if t == "gridfleet/v1/replies/op"]
    return reply["accepted"], reply["reason"]


def energy_view(effects: Effects) -> Any:
    """The one energy view among `effects` (its header left out)."""
    (view,) = [p for topic, p, qos, retain in published(effects) if topic == ENERGY]
    assert view.pop("header")["sender"] == "coordinator"
    return view


def events(effects: Effects) -> list[str]:
    return [e.text for e in effects.events]


def plans(core: CoordinatorCore) -> dict[str, str]:
    return {u: e.plan for u, e in core.energy.units_view().items()}


def control(core: CoordinatorCore, unit: str, now: float = 0.5) -> Any:
    """An operator's `charge` for `unit`; its reply's (accepted, reason)."""
    req = ControlUnit(
        header=header("op"), request_id=f"c-{unit}", reply_to="op", unit=unit, command="charge"
    )
    effects = request(core, "control_unit", req, now)
    (reply,) = [p for t, p, *_ in published(effects) if t == "gridfleet/v1/replies/op"]
    return reply["accepted"], reply["reason"]
