"""A coordinator that starts without the units' retained records learns them anyway (§5.5).

RabbitMQ keeps retained messages per node and never delivers them to a wildcard subscription
(`units/+/factsheet`); a broker restarted without persistence has none. Here on the embedded
broker: the coordinator stops, a probe clears every unit's retained `factsheet` and
`connection` (empty retained payloads), and a new coordinator starts. The units, reading its
first `online`, tell it who they are again: it learns every factsheet, and a job is allocated
and done.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import pytest
from test_failover_stop import ROOT, SCENARIO, STEP_S, T

from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import coordinator_thread, fleet_thread

from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.wait import wait_for

UNITS = sorted(u.id for u in SCENARIO.units)


def retained_records(url: str) -> dict[str, bytes]:
    """The units' retained factsheets and connections a client subscribing to `url` reads now."""
    with MqttProbe(url) as probe:
        probe.subscribe(T.all_units("factsheet"))
        probe.subscribe(T.all_units("connection"))
        probe.subscribe(f"{ROOT}/marker")
        probe.publish(f"{ROOT}/marker", b"m")  # comes back after the retained ones
        probe.wait(f"{ROOT}/marker")
        kinds = ("factsheet", "connection")
        seen = [m for k in kinds for u in UNITS for m in probe.received(T.unit(k, u))]
        return {m.topic: m.payload for m in seen if m.retain and m.payload}


# Two coordinator starts, four units and a job on a shared 2-core host: about 20 s, with margin.
@pytest.mark.timeout(150)
def test_a_coordinator_started_without_the_units_retained_records_learns_them_again(
    tmp_path: Path,
) -> None:
    with BrokerThread() as broker, ExitStack() as stack:
        first = coordinator_thread(
            SCENARIO, broker.url, root=ROOT, step_s=STEP_S, db_path=tmp_path / "first.db"
        ).start(30)
        first_stop = stack.enter_context(ExitStack())
        first_stop.callback(first.stop, 30)
        fleet = fleet_thread(SCENARIO, broker.url, root=ROOT, step_s=STEP_S).start(30)
        stack.callback(fleet.stop, 30)  # stopped before the broker, also on failure
        world = first.service.core.world

        def known() -> list[str]:
            return sorted(u for u, r in world.units.items() if r.factsheet is not None)

        wait_for(lambda: first.call(known) == UNITS, 20, what="every unit known")
        first_stop.close()  # the first coordinator stops (its clean `offline`)
        # What the broker kept of the units is gone: nothing retained to read on subscribing.
        with MqttProbe(broker.url) as probe:
            for unit in UNITS:
                for kind in ("factsheet", "connection"):
                    probe.publish(T.unit(kind, unit), b"", qos=1, retain=True)
        assert retained_records(broker.url) == {}
        second = coordinator_thread(
            SCENARIO, broker.url, root=ROOT, step_s=STEP_S, db_path=tmp_path / "second.db"
        ).start(30)
        stack.callback(second.stop, 30)
        core = second.service.core
        again = core.world

        def learnt() -> dict[str, tuple[float | None, str | None]]:
            return {
                u: (r.capacity_kg, r.connection)
                for u, r in again.units.items()
                if r.factsheet is not None
            }

        capacities = {u.id: (u.capacity, "online") for u in SCENARIO.units}
        wait_for(lambda: second.call(learnt) == capacities, 20, what="every unit again")
        # Retained again, for any reader that comes later.
        assert len(retained_records(broker.url)) == 2 * len(UNITS)
        spec = SCENARIO.jobs[0]
        with MqttProbe(broker.url) as probe:
            operator = OperatorPeer(probe, T, "ann")
            reply = operator.submit_job(spec.pickup, spec.dropoff, spec.mass, job_id="j1")
            assert reply.accepted, reply

        def state() -> tuple[str, str | None]:
            job = core.jobs.jobs["j1"]
            return job.state, job.unit

        wait_for(lambda: second.call(state)[0] == "done", 45, what="the job done")
        assert second.call(state)[1] in UNITS
