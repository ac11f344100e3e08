"""Job allocation: queued jobs to idle units under capacity, minimising total true travel.

Pure: units (square, free capacity) and jobs (pickup, dropoff, mass, priority) in, pairs out.
Costs are path lengths from BFS distance fields (not straight lines); the optimum comes from an
assignment solver (Hungarian method, `scipy.optimize.linear_sum_assignment`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gridfleet.coordinator.energy import CHARGE_PREFERENCE
from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE, DistanceFieldCache

INFEASIBLE = 1e12  # cost of a pair that must never be chosen (filtered after solving)


@dataclass(frozen=True)
class UnitSlot:
    """An idle unit: where it is and how much more it can carry."""

    id: str
    position: Cell
    capacity_kg: float
    # Its energy (coordinator/energy.py): the most squares it may drive on a job, to the charger
    # after it; whether no charger can be reached (the way then ends at the dropoff); its charge.
    max_moves: float = math.inf
    stranded: bool = False
    charge_pct: float = 100.0


@dataclass(frozen=True)
class JobRequest:
    """A queued job as allocation sees it."""

    id: str
    pickup: Cell
    dropoff: Cell
    mass_kg: float
    priority: int = 0
    to_charger: int | None = 0  # squares from the dropoff to its nearest charger (None: none)


def feasible(cache: DistanceFieldCache, unit: UnitSlot, job: JobRequest) -> int | None:
    """Travel of `unit` to do `job` (to pickup, then to dropoff), or None if it cannot."""
    if job.mass_kg > unit.capacity_kg:
        return None
    to_pickup = cache.distance(unit.position, job.pickup)
    if to_pickup == UNREACHABLE:
        return None
    carry = cache.distance(job.dropoff, job.pickup)  # the pickup's field: see `allocate`
    if carry == UNREACHABLE:
        return None
    return to_pickup + carry


def allocate(
    cache: DistanceFieldCache, units: Sequence[UnitSlot], jobs: Sequence[JobRequest]
) -> dict[str, str]:
    """Job id → unit id for an optimal set of pairs; capacity and reachability always hold.

    Higher-priority jobs win when there are more jobs than units: each priority point outweighs
    any travel on the map. Among equal priorities the total travel is minimal, each % of charge
    a unit lacks counting as CHARGE_PREFERENCE squares more (the work spreads over the units
    with charge). A unit with energy gets only a job it can finish: to the pickup, the dropoff
    and the charger nearest it within its `max_moves` (energy.py).
    """
    if not units or not jobs:
        return {}
    grid = cache.grid
    lack = np.array([CHARGE_PREFERENCE * (100.0 - u.charge_pct) for u in units])
    # More than any travel on this map, with the preference for charge.
    weight = float(grid.width * grid.height * 2 + 1 + CHARGE_PREFERENCE * 100)
    cost = np.full((len(jobs), len(units)), INFEASIBLE)
    # One row at a time, all units at once: what `feasible` says of each pair, in numpy (a
    # Python loop over pairs took most of a tick with hundreds of idle units and queued jobs).
    inside = np.array([grid.in_bounds(u.position) for u in units])
    at = np.array([u.position.y * grid.width + u.position.x for u in units]) * inside
    capacity = np.where(inside, [u.capacity_kg for u in units], -np.inf)  # off the map: none
    budget = np.array([u.max_moves for u in units], dtype=float)
    limited = np.isfinite(budget)
    stranded = np.array([u.stranded for u in units])
    for r, job in enumerate(jobs):
        # Read off the pickup's field (the grid is undirected: the same length): jobs share a
        # few pickups but rarely a dropoff, and a field per dropoff made thousands of BFS.
        carry = cache.distance(job.dropoff, job.pickup)
        if carry == UNREACHABLE:
            continue
        to_pickup = cache.distances(job.pickup, at)
        ok = (to_pickup != UNREACHABLE) & (capacity >= job.mass_kg)
        if limited.any():
            leg = np.where(stranded, job.to_charger or 0, _leg(job.to_charger))
            way = to_pickup.astype(float) + carry + leg
            ok &= ~limited | (way <= budget)
        cost[r, ok] = to_pickup[ok] + carry + lack[ok] - weight * job.priority
    # Imported here, as scipy is in gridfleet.paths (which says why).
    from scipy.optimize import linear_sum_assignment

    rows, cols = linear_sum_assignment(cost)
    return {
        jobs[r].id: units[c].id
        for r, c in zip(rows.tolist(), cols.tolist(), strict=True)
        if cost[r, c] < INFEASIBLE / 2
    }


def _leg(to_charger: int | None) -> float:
    """The way on from a dropoff to its nearest charger (none reachable: no unit may go)."""
    return math.inf if to_charger is None else float(to_charger)


def capacity_reason(mass_kg: float, capacities: Sequence[float]) -> str | None:
    """Why no known unit could ever carry `mass_kg`, or None when one could (or none known)."""
    if not capacities:
        return None
    largest = max(capacities)
    if mass_kg > largest:
        return f"mass {mass_kg} kg exceeds every unit's capacity (largest {largest} kg)"
    return None


def reach_reason(
    cache: DistanceFieldCache,
    pickup: Cell,
    dropoff: Cell,
    mass_kg: float,
    units: Sequence[tuple[Cell, float]],
) -> str | None:
    """Why no unit able to carry `mass_kg` could ever do the job (walls and known obstacles), or
    None when one could (or none is known yet). `units`: (square, capacity) of every unit known."""
    capable = [square for square, capacity in units if capacity >= mass_kg]
    if not capable:
        return None  # capacity_reason says why, or no unit is known yet: wait
    if cache.distance(pickup, dropoff) == UNREACHABLE:
        return f"dropoff {list(dropoff)} cannot be reached from pickup {list(pickup)}"
    if all(cache.distance(square, pickup) == UNREACHABLE for square in capable):
        return f"no unit that can carry {mass_kg} kg can reach pickup {list(pickup)}"
    return None
