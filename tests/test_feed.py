"""The demo feed's random jobs: feasible, and sized to the fleet's mix of units."""

from __future__ import annotations

import random
from pathlib import Path

from gridfleet.paths import UNREACHABLE, DistanceFieldCache
from gridfleet.scenario import load_scenario
from system.feed import random_job

WAREHOUSE = Path(__file__).resolve().parent.parent / "maps" / "warehouse.toml"


def test_demo_jobs_fit_the_fleets_mix_and_every_one_can_be_done() -> None:
    # The hour-long warehouse demo: masses up to the biggest capacity went mostly to the four
    # big units while eight small ones idled.
    scenario = load_scenario(WAREHOUSE)
    fields = DistanceFieldCache(scenario.grid)
    capacities = sorted(u.capacity for u in scenario.units)
    jobs = [random_job(scenario, random.Random(seed), fields) for seed in range(400)]
    home = scenario.units[0].start
    for pickup, dropoff, mass in jobs:
        assert 0 < mass <= capacities[-1] and pickup != dropoff
        assert UNREACHABLE not in (fields.distance(home, pickup), fields.distance(home, dropoff))
    small = capacities[0]
    share_small_units = sum(c <= small for c in capacities) / len(capacities)
    share_small_jobs = sum(mass <= small for _, _, mass in jobs) / len(jobs)
    # About as many jobs fit the smallest units as there are such units (a fifth of the jobs
    # before, a uniform draw up to the biggest capacity, for a third of the units).
    assert share_small_jobs >= 0.8 * share_small_units, (share_small_jobs, share_small_units)
