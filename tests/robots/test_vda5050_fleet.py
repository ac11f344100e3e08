"""VDA 5050 vehicles in a real fleet: the coordinator and simulated units of gridfleet, the adapter,
and vehicles of our own (VDA 5050 2.1.0, and 2.0.0) on one broker, every message of the vehicles',
both ways, held to the official schema; safety judged from every state seen on the bus."""

from __future__ import annotations

import json
import shutil
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest

from gridfleet.grid import Cell
from gridfleet.protocol import EnergyModel, Topics, UnitState, VehicleCondition, decode
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.shell import AdapterShell
from gridfleet.robots.vda5050.virtual import Quirk, VirtualSpec
from gridfleet.robots.vda5050.virtual_shell import VirtualVehicleShell
from gridfleet.robots.vda5050.wire import Vehicle, Version
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.operator_peer import OperatorPeer
from support.paths import MAPS
from support.probe import MqttProbe
from support.vda import official_if_here
from support.wait import wait_for

# Once, on the embedded broker: these are about the adapter and the vehicle; the vehicles nobody
# here wrote (test_vda5050_lib.py) run on Mosquitto too.
pytestmark = [pytest.mark.slow, pytest.mark.amqtt_only]

FRAME = Frame("hall")  # square (0, 0) at the origin, 0.1 m squares, y up
STEP = 0.1
# The adapter's clock (and the step period its units' factsheets give, which sets how long the
# coordinator waits on their silence): longer than the fleet's, so that a machine shared with
# other test workers does not make a vehicle's unit look lost between two heartbeats.
ADAPTER_STEP = 0.2


def scenario(tmp_path: Path) -> Path:
    """The playfield with two of gridfleet's units (no hidden obstacles: a vehicle has no sensor
    of gridfleet's to find one)."""
    shutil.copy(MAPS / "playfield.map", tmp_path / "playfield.map")
    path = tmp_path / "mixed.toml"
    path.write_text(
        'name = "mixed"\nmap = "playfield.map"\n'
        '[[units]]\nid = "unit1"\nstart = [0, 0]\ncapacity = 2.0\n'
        '[[units]]\nid = "unit2"\nstart = [9, 0]\ncapacity = 5.0\n',
        encoding="utf-8",
    )
    return path


@dataclass(frozen=True)
class Agv:
    """A virtual vehicle of the fleet: its unit, serial number, square, capacity and version."""

    unit: str
    serial: str
    at: Cell
    capacity_kg: float
    version: Version = "2.1.0"


AGV1 = Agv("agv1", "v-1", Cell(0, 9), 3.0)


class Vehicles:
    """The adapter and its virtual vehicles, each in a thread of its own."""

    def __init__(self, broker: BrokerThread, root: str, grid: Any) -> None:
        self.virtual: dict[str, VirtualVehicleShell] = {}
        self.configs: list[VehicleConfig] = []
        self.threads: list[ServiceThread[Any]] = []
        self.broker, self.root, self.grid = broker, root, grid

    def add(
        self, agv: Agv, speed: float = 1.0, energy: EnergyModel | None = None, **spec: Any
    ) -> None:
        """A virtual vehicle (`spec`: its VirtualSpec's fields); `energy`: its vehicles file's."""
        unit, at, capacity_kg = agv.unit, agv.at, agv.capacity_kg
        vehicle = Vehicle(unit, "gridfleet", agv.serial, agv.version)
        # A 2.1 vehicle's capacity comes from its factsheet; a 2.0 one's from the vehicles file.
        configured = capacity_kg if agv.version == "2.0.0" else None
        self.configs.append(VehicleConfig(vehicle, FRAME, configured, 0.0, False, energy=energy))
        start = FRAME.position(at)
        self.virtual[unit] = VirtualVehicleShell(
            vehicle,
            VirtualSpec(
                start, FRAME.map_id, speed=speed, capacity_kg=capacity_kg, action_s=0.2, **spec
            ),
            self.broker.url,
        )

    def start(self) -> None:
        for unit, shell in self.virtual.items():
            self.threads.append(ServiceThread(lambda s=shell: s, f"vehicle-{unit}").start())
        schemas = official_if_here()
        adapter = ServiceThread(
            lambda: AdapterShell(
                self.configs,
                self.grid,
                self.broker.url,
                Topics(self.root),
                step_s=ADAPTER_STEP,
                schemas=schemas,
            ),
            "vda5050",
        )
        self.threads.append(adapter.start())

    def stop(self) -> None:
        for thread in reversed(self.threads):
            thread.stop()


@pytest.fixture
def vehicles(broker: BrokerThread, root: str, tmp_path: Path) -> Iterator[Callable[[], Vehicles]]:
    made: list[Vehicles] = []

    def make() -> Vehicles:
        from gridfleet.scenario import load_scenario

        made.append(Vehicles(broker, root, load_scenario(scenario(tmp_path)).grid))
        return made[-1]

    yield make
    for v in made:
        v.stop()


class Judge:
    """Every unit state seen on the bus, in order: no two units ever on one square.

    A unit reports a square only once it is on it, so a swap (A to B as the other goes B to A)
    shows as two units on one square whichever state comes first.
    """

    def __init__(self) -> None:
        self.where: dict[str, Cell] = {}
        self.faults: list[str] = []
        self.seen = 0
        self.lock = threading.Lock()

    def see(self, unit: str, state: UnitState) -> None:
        with self.lock:
            self.seen += 1
            square = Cell(*state.position)
            self.where[unit] = square
            for other, there in self.where.items():
                if other != unit and there == square:
                    self.faults.append(f"{unit} and {other} both on {list(square)}")


@dataclass
class Mixed:
    """The running mixed fleet, what the test sees of it, and the vehicle."""

    operator: OperatorPeer
    judge: Judge
    coordinator: ServiceThread[Any]
    vehicles: Vehicles

    @property
    def agv1(self) -> VirtualVehicleShell:
        return self.vehicles.virtual["agv1"]


@pytest.fixture
def mixed_fleet(
    run_system: Callable[..., Any],
    vehicles: Callable[[], Vehicles],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
    tmp_path: Path,
) -> Iterator[Callable[..., Mixed]]:
    """Factory: unit1 (2 kg) and unit2 (5 kg) of gridfleet's and the vehicles `agvs` (by default
    a 2.1.0 vehicle agv1 of 3 kg by its factsheet at (0, 9)), each with `quirks`, on the
    playfield, known to the coordinator."""
    made: list[Mixed] = []

    def start(
        quirks: frozenset[Quirk] = frozenset(), speed: float = 1.0, agvs: tuple[Agv, ...] = (AGV1,)
    ) -> Mixed:
        judge = Judge()
        probe = probe_factory()
        probe.client.message_callback_add(
            topics.all_units("state"),
            lambda c, u, m: judge.see(m.topic.split("/")[-2], decode(UnitState, m.payload)),
        )
        probe.subscribe(topics.all_units("state"), qos=0)
        operator = OperatorPeer(probe_factory(), topics, "tester")
        coordinator, _ = run_system(scenario(tmp_path), step_s=STEP)
        fleet = vehicles()
        for agv in agvs:
            fleet.add(agv, speed=speed, quirks=quirks)
        fleet.start()
        world = coordinator.service.world
        capacities = sorted([2.0, 5.0, *(agv.capacity_kg for agv in agvs)])
        wait_for(
            lambda: coordinator.call(lambda: sorted(world.capacities())) == capacities,
            timeout=20,
            what="the coordinator knows the units and the vehicles (a 2.1 one by its factsheet)",
        )
        made.append(Mixed(operator, judge, coordinator, fleet))
        return made[-1]

    yield start
    for m in made:
        m.operator.raw_estop(b"")


@pytest.fixture
def mixed(mixed_fleet: Callable[..., Mixed]) -> Mixed:
    """The mixed fleet with a vehicle that does as it is told."""
    return mixed_fleet()


@pytest.mark.timeout(180)
def test_a_2_1_vehicle_beside_gridfleets_units_finishes_its_jobs_safely_and_by_its_factsheet(
    mixed: Mixed,
) -> None:
    operator = mixed.operator
    jobs = {
        "light-1": (Cell(1, 8), Cell(8, 8), 1.0),
        "light-2": (Cell(5, 9), Cell(9, 5), 2.5),  # over unit1's 2 kg: the vehicle or unit2
        "heavy": (Cell(1, 5), Cell(8, 3), 4.0),  # over the vehicle's 3 kg: only unit2
        "light-3": (Cell(0, 6), Cell(5, 0), 1.5),
    }
    for job_id, (pickup, dropoff, mass) in jobs.items():
        assert operator.submit_job(pickup, dropoff, mass, job_id=job_id).accepted
    wait_for(lambda: operator.all_final(list(jobs)), timeout=120, what="every job final")
    listed = operator.listed_jobs()
    assert {j: listed[j].state for j in jobs} == dict.fromkeys(jobs, "done")
    assert listed["heavy"].unit == "unit2"
    vda_jobs = {j for j in jobs if listed[j].unit == "agv1"}
    assert vda_jobs, {j: listed[j].unit for j in jobs}  # the vehicle did its share
    carried = {s.job_id for s in operator.states("agv1") if s.job_id is not None}
    assert vda_jobs <= carried
    assert mixed.judge.faults == [] and mixed.judge.seen > 50
    # Its own condition, retained for whoever looks (the dashboard, gridfleet status).
    told_on = operator.topics.unit("vehicle", "agv1")
    operator.probe.subscribe(told_on)
    told = decode(VehicleCondition, operator.probe.wait(told_on).payload)
    assert (told.battery_pct, told.charging, told.errors) == (90.0, False, [])
    # Both ways, every message of the vehicle's is valid against the official 2.1.0 schemas.
    schemas = official_if_here()
    virtual = mixed.agv1
    for name, message in [*virtual.received, *virtual.sent] if schemas is not None else []:
        assert schemas.problems("2.1.0", name, message) == [], (name, message)
    assert {name for name, _ in virtual.received} >= {"order", "instantActions"}
    # Stamped with the time of day (the adapter once wrote its monotonic clock: 1970).
    for _, message in virtual.received:
        sent_at = datetime.fromisoformat(message["timestamp"].replace("Z", "+00:00"))
        assert abs(sent_at.timestamp() - time.time()) < 600, message["timestamp"]


def _agv1_job(operator: OperatorPeer, pickup: Cell) -> str:
    """A 2.5 kg job from up agv1's column across the map: too heavy for unit1, far from unit2."""
    assert operator.submit_job(pickup, Cell(9, 9), 2.5, job_id="crate").accepted
    wait_for(
        lambda: (s := operator.last_state("agv1")) is not None and s.status == "moving",
        timeout=20,
        what="agv1 on its way",
    )
    wait_for(
        lambda: operator.listed_jobs()["crate"].unit == "agv1", timeout=20, what="crate to agv1"
    )
    return "crate"


@pytest.mark.timeout(120)
def test_the_fleet_stop_pauses_the_vehicle_where_it_is_and_the_release_resumes_it(
    mixed: Mixed,
) -> None:
    operator, virtual = mixed.operator, mixed.agv1
    job = _agv1_job(operator, Cell(0, 6))
    operator.engage("test")
    wait_for(lambda: virtual.core.paused, timeout=10, what="the vehicle paused")
    paused = [m for n, m in virtual.received if n == "instantActions"]
    assert [a["actionType"] for a in paused[-1]["actions"]] == ["startPause"]
    where = (virtual.core.x, virtual.core.y)
    # Measuring over a span of time: it stays where the pause found it (the stopping distance
    # of this vehicle is nothing), and the unit says it is stopped.
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        assert (virtual.core.x, virtual.core.y) == where
        time.sleep(0.05)
    wait_for(
        lambda: (s := operator.last_state("agv1")) is not None and s.status == "stopped",
        timeout=10,
        what="agv1 stopped",
    )
    operator.release("checked")
    wait_for(lambda: not virtual.core.paused, timeout=10, what="the vehicle resumed")
    wait_for(lambda: operator.job_state(job) == "done", timeout=60, what="the job done")
    assert mixed.judge.faults == []


# Slow, and sent far: the kill must come before agv1 holds its pickup (a lost unit's squares stay
# reserved, protocol.md §8) or carries the item (then only agv1 may finish the job). At 2 s a
# square, agv1 is released the pickup 6 squares up no sooner than some 8 s after it set off.
DYING_SPEED_M_S = 0.05
FAR_PICKUP = Cell(0, 3)


def assert_not_at_its_pickup(operator: OperatorPeer, unit: str, pickup: Cell) -> None:
    """A killed vehicle's test's premise: the fleet last heard `unit` hold and carry none of it."""
    heard = operator.last_state(unit)
    held = set() if heard is None else {heard.position, *heard.released}
    assert heard is not None and heard.load_kg == 0 and pickup not in held, (
        f"{unit} held its pickup before the kill: {heard}"
    )


def where(operator: OperatorPeer, job: str, units: tuple[str, ...]) -> str:
    """Where a job and some units stand: to tell a stall from a slow run."""
    lines = [repr(operator.listed_jobs().get(job))]
    lines += [f"{unit}: {operator.last_state(unit)}" for unit in units]
    return "\n".join(lines)


@pytest.mark.timeout(120)
def test_a_vehicle_that_dies_is_lost_and_its_job_goes_to_another_unit(
    mixed_fleet: Callable[..., Mixed],
) -> None:
    mixed = mixed_fleet(speed=DYING_SPEED_M_S)
    operator = mixed.operator
    job = _agv1_job(operator, FAR_PICKUP)
    mixed.agv1.kill()  # its last will: CONNECTIONBROKEN
    assert_not_at_its_pickup(operator, "agv1", FAR_PICKUP)
    wait_for(lambda: operator.connections("agv1")[-1:] == ["broken"], timeout=20, what="agv1 lost")
    wait_for(
        lambda: operator.job_state(job) == "done",
        timeout=90,
        what="the job done",
        context=lambda: where(operator, job, ("agv1", "unit2")),
    )
    assert operator.listed_jobs()[job].unit == "unit2"
    assert mixed.judge.faults == []


# Heavier than any of gridfleet's units carries (2 and 5 kg): only the vehicles can take them.
HEAVY_KG = 25.0
WEIGHTLESS = (
    Agv("agv1", "v-1", Cell(0, 9), HEAVY_KG, "2.1.0"),
    Agv("agv2", "v-2", Cell(9, 9), HEAVY_KG, "2.0.0"),
)
HEAVY_JOBS = {
    "heavy-1": ("agv1", Cell(0, 6), Cell(2, 9)),  # by agv1: a few squares up its column
    "heavy-2": ("agv2", Cell(9, 6), Cell(7, 9)),  # by agv2, as far from agv1 as the map allows
}


@pytest.mark.timeout(180)
def test_vehicles_whose_loads_carry_no_weight_finish_heavy_jobs_only_they_can_carry(
    mixed_fleet: Callable[..., Mixed],
) -> None:
    # Issue 53: vehicles written from the spec (2.0.0 and 2.1.0) name their load without a weight
    # once they have picked (the schemas' load requires no field); the adapter dropped every
    # state after that (a TypeError) and their jobs froze at the pickup.
    mixed = mixed_fleet(frozenset({"weightless_loads"}), agvs=WEIGHTLESS)
    operator = mixed.operator
    for job_id, (_, pickup, dropoff) in HEAVY_JOBS.items():
        assert operator.submit_job(pickup, dropoff, HEAVY_KG, job_id=job_id).accepted
    wait_for(
        lambda: operator.all_final(list(HEAVY_JOBS)),
        timeout=120,
        what="both heavy jobs final",
        context=lambda: where(operator, "heavy-1", ("agv1", "agv2")),
    )
    listed = operator.listed_jobs()
    assert {j: (listed[j].state, listed[j].unit) for j in HEAVY_JOBS} == {
        j: ("done", unit) for j, (unit, _, _) in HEAVY_JOBS.items()
    }
    for job_id, (unit, _, _) in HEAVY_JOBS.items():
        virtual = mixed.vehicles.virtual[unit]
        loads = [load for n, m in virtual.sent if n == "state" for load in m["loads"]]
        assert loads and all("weight" not in load for load in loads), (unit, loads)
        # The fleet knows the job: from the pick to the drop the unit carries the job's mass.
        carried = {s.load_kg for s in operator.states(unit) if s.job_id == job_id}
        assert carried == {HEAVY_KG}, (unit, carried)
    assert mixed.judge.faults == []
    schemas = official_if_here()
    for agv in WEIGHTLESS if schemas is not None else ():
        virtual = mixed.vehicles.virtual[agv.unit]
        for name, message in [*virtual.received, *virtual.sent]:
            assert schemas.problems(agv.version, name, message) == [], (agv.unit, name, message)


JOBS = {
    "light-1": (Cell(1, 8), Cell(8, 8), 1.0),
    "light-2": (Cell(5, 9), Cell(9, 5), 2.5),
    "light-3": (Cell(0, 6), Cell(5, 0), 1.5),
}


@pytest.mark.timeout(180)
@pytest.mark.parametrize("quirk", ["reject_updates", "no_route"])
def test_a_vehicle_refusing_what_the_spec_lets_it_refuse_strands_no_job(
    mixed_fleet: Callable[..., Mixed], quirk: Quirk
) -> None:
    # Refusing every update, it drives each order's first release and stops: its orders end
    # there and start anew. Refusing every route, it never moves: it is lost to the fleet.
    mixed = mixed_fleet(frozenset({quirk}))
    operator = mixed.operator
    for job_id, (pickup, dropoff, mass) in JOBS.items():
        assert operator.submit_job(pickup, dropoff, mass, job_id=job_id).accepted
    wait_for(
        lambda: operator.all_final(list(JOBS)),
        timeout=150,
        what="every job final",
        context=lambda: (
            operator.listed_jobs(),
            {u: operator.last_state(u) for u in ("unit1", "unit2", "agv1")},
        ),
    )
    listed = operator.listed_jobs()
    assert {j: listed[j].state for j in JOBS} == dict.fromkeys(JOBS, "done"), listed
    assert mixed.judge.faults == []
    refusals = [e["errorType"] for n, m in mixed.agv1.sent if n == "state" for e in m["errors"]]
    if quirk == "no_route":
        assert "noRouteError" in refusals
        assert operator.connections("agv1")[-1] == "broken"
        assert all(listed[j].unit != "agv1" for j in JOBS)
    else:
        assert "orderUpdateError" in refusals
        assert any(listed[j].unit == "agv1" for j in JOBS)  # it still did its share


@pytest.mark.timeout(120)
def test_a_cancelled_job_cancels_the_vehicles_order_and_it_ends_idle(mixed: Mixed) -> None:
    operator, virtual = mixed.operator, mixed.agv1
    job = _agv1_job(operator, Cell(0, 6))
    assert operator.cancel_job(job).accepted
    wait_for(
        lambda: any(
            a["actionType"] == "cancelOrder"
            for n, m in virtual.received
            if n == "instantActions"
            for a in m["actions"]
        ),
        timeout=10,
        what="cancelOrder sent",
    )
    wait_for(
        lambda: (
            (s := operator.last_state("agv1")) is not None
            and s.status == "idle"
            and not s.released
            and s.job_id is None
        ),
        timeout=20,
        what="agv1 idle, nothing released, carrying nothing",
    )
    # The queue view follows within a period (protocol.md §5.3), not necessarily before the state.
    wait_for(lambda: operator.job_state(job) == "cancelled", timeout=10, what="listed cancelled")
    assert not virtual.core.nodes and not virtual.core.driving
    # And it takes the next job as before.
    assert operator.submit_job(Cell(0, 6), Cell(9, 8), 2.5, job_id="next").accepted
    wait_for(lambda: operator.job_state("next") == "done", timeout=60, what="the next job done")
    assert mixed.judge.faults == []


@pytest.mark.timeout(120)
def test_bad_messages_on_a_vehicles_topics_are_reported_and_the_fleet_runs_on(
    mixed: Mixed,
) -> None:
    operator, virtual = mixed.operator, mixed.agv1
    good = virtual.core.state(time.time())
    bad = {
        "state": [b"{not json", json.dumps({**good, "driving": "yes"}).encode()],
        "connection": [json.dumps({**good, "connectionState": "ASLEEP"}).encode()],
        "factsheet": [b"\xff\xfe"],
    }
    with MqttProbe(mixed.vehicles.broker.url) as intruder:
        for name, payloads in bad.items():
            for payload in payloads:
                intruder.publish(virtual.vehicle.topic(name), payload, qos=1)
    wait_for(
        lambda: sum("vehicle agv1: refused" in e.reason for e in operator.errors()) >= 4,
        timeout=10,
        what="every bad message reported",
    )
    assert operator.connections("agv1")[-1] == "online"  # none of it changed anything
    job = _agv1_job(operator, Cell(0, 6))  # and it still drives
    wait_for(lambda: operator.job_state(job) == "done", timeout=60, what="the job done")


@pytest.mark.timeout(120)
def test_an_operators_pause_of_the_vehicles_unit_pauses_the_vehicle_and_resume_resumes_it(
    mixed: Mixed,
) -> None:
    operator, virtual = mixed.operator, mixed.agv1
    job = _agv1_job(operator, Cell(0, 6))
    sent = operator.send_control_unit("agv1", "pause")
    assert operator.reply_to(sent.request_id).accepted
    wait_for(lambda: virtual.core.paused, timeout=10, what="the vehicle paused")
    sent = operator.send_control_unit("agv1", "resume")
    assert operator.reply_to(sent.request_id).accepted
    wait_for(lambda: not virtual.core.paused, timeout=10, what="the vehicle resumed")
    wait_for(lambda: operator.job_state(job) == "done", timeout=60, what="the job done")
    assert mixed.judge.faults == []
