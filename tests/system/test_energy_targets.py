"""Issue 54's targets: lifelong work on batteries, every job done, no unit empty or overreached."""

from __future__ import annotations

from collections import defaultdict

import pytest

from gridfleet.scenario import load_scenario
from gridfleet.system.lockstep import Lockstep

from support.paths import MAPS
from support.scripts import load_script


def test_the_shipped_energy_scenarios_are_what_their_script_writes() -> None:
    script = load_script("gen_energy_scenarios")
    for spec in script.SCENARIOS:
        shipped = (MAPS / f"{spec.name}.toml").read_text(encoding="utf-8")
        assert shipped == script.render(spec), f"run script/gen_energy_scenarios.py ({spec.name})"


@pytest.mark.timeout(180)  # over 60 s on a slow make test run (fresh clone, 2026-12-02)
@pytest.mark.slow  # 300 jobs in lockstep (about 15 s): make test, not test-fast
def test_the_energy_warehouse_does_every_job_on_several_charges_and_none_runs_empty() -> None:
    scenario = load_scenario(MAPS / "warehouse-energy.toml")
    sim = Lockstep(scenario, 0.02, seed=0)  # simulate --deterministic's default step
    sim.start()
    sim.submit_scenario()
    given: dict[str, list[str]] = defaultdict(list)  # each job's units, in turn
    while sim.core.step_no < 5000 and not sim.finished():
        sim.step()
        for job in sim.core.jobs.jobs.values():
            if job.unit is not None and (not given[job.id] or given[job.id][-1] != job.unit):
                given[job.id].append(job.unit)
    assert sim.finished(), f"{sim.core.step_no} steps"
    jobs = sim.core.jobs.jobs.values()
    assert len(jobs) == 300 and {j.state for j in jobs} == {"done"}
    assert sim.world.collisions == 0
    # Never sent on a job it could not finish: each job went to one unit, which did it.
    assert {
        job.id: units for job, units in ((j, given[j.id]) for j in jobs) if units != [job.unit]
    } == {}
    for unit in sim.units:
        battery = unit.logic.battery
        assert battery is not None
        assert not battery.reached_empty and battery.lowest_pct > 0, unit.id
        assert battery.charges >= 2, (unit.id, battery.charges)  # a lifelong load: several charges


# Over MQTT, every shipped scenario (these among them) runs through `gridfleet simulate` in
# tests/system/test_simulate.py, which checks the batteries of the *-energy ones too.
