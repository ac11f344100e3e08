"""A factsheet that comes after the coordinator took the fleet for known is taken (§5.5).

On RabbitMQ a coordinator that (re)starts gets no unit's retained `connection` nor `factsheet`
(each node keeps its own, and none reaches a wildcard subscription): it hears the units' states
live, its own status back, and after FLEET_KNOWN_AFTER_S takes the fleet for known. The units
then tell the new session who they are again; the late factsheet makes the unit allocatable.
"""

from __future__ import annotations

from gridfleet.coordinator.world import FLEET_KNOWN_AFTER_S
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import Connection, Factsheet, SubmitJob
from gridfleet.robots.unit import UnitLogic

from support.coordinator_drive import (
    from_unit,
    make_core,
    orders_in,
    reply_in,
    request,
    step_hearing_itself,
)
from support.coordinator_fakes import ROOM_ROWS, Yard
from support.effects import header


def test_a_unit_whose_factsheet_comes_after_the_fleet_was_known_is_given_a_job() -> None:
    grid = GridMap.from_rows(ROOM_ROWS)
    core = make_core(grid)
    core.world.fleet_known_after_s = FLEET_KNOWN_AFTER_S  # as a coordinator started for real
    yard = Yard(grid, [UnitLogic("u", grid, Cell(0, 0), 5.0, 1.0)])
    unit = yard.units["u"]
    unit.start(0.0)
    submit = SubmitJob(
        header=header("t"),
        request_id="r1",
        reply_to="t",
        pickup=Cell(3, 0),
        dropoff=Cell(6, 0),
        mass_kg=2.0,
    )
    answer = reply_in(request(core, "submit_job", submit, 0.0))
    assert answer.accepted and answer.job_id is not None
    job = core.jobs.jobs[answer.job_id]

    def step(now: float) -> bool:
        """One step heard back; the unit follows its order and its state arrives, live."""
        orders = orders_in(step_hearing_itself(core, now))
        if "u" in orders:
            unit.on_order(orders["u"], now)
        yard.tick("u", now)
        from_unit(core, "state", "u", yard.state("u"), now)
        return "u" in orders

    # Its states come, its retained connection and factsheet never do: no job for it, whatever
    # long the coordinator listens, and the fleet counts as known all the same.
    now = 0.0
    while now < FLEET_KNOWN_AFTER_S + 3.0:
        now += 1.0
        step(now)
        assert job.state == "queued" and job.unit is None, (now, job.state)
    assert core.world.fleet_known()
    assert core.world.units["u"].factsheet is None
    # The unit tells the new session who it is again: `online`, the factsheet, its state.
    from_unit(core, "connection", "u", Connection(header=header("u", 5), state="online"), now)
    fs = Factsheet(header=header("u", 5), capacity_kg=5.0, step_period_s=1.0)
    from_unit(core, "factsheet", "u", fs, now)
    from_unit(core, "state", "u", yard.state("u"), now)
    assert core.world.units["u"].capacity_kg == 5.0
    for _ in range(60):
        now += 1.0
        step(now)
        if job.state == "done":
            break
    assert (job.state, job.unit) == ("done", "u")
