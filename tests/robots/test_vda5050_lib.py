"""VDA 5050 2.0.0 vehicles nobody here wrote: `vda-5050-lib`'s virtual AGVs (1.4.0, its
AgvController and VirtualAgvAdapter, in Node.js) beside gridfleet's units, under one planner and
one stop; every VDA 5050 message of the run, both ways, held to the official 2.0.0 schemas."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from test_vda5050_fleet import (
    ADAPTER_STEP,
    DYING_SPEED_M_S,
    FAR_PICKUP,
    STEP,
    Judge,
    assert_not_at_its_pickup,
    scenario,
    where,
)

from gridfleet.grid import Cell
from gridfleet.protocol import Topics, UnitState, decode
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.orders import node_id
from gridfleet.robots.vda5050.shell import AdapterShell
from gridfleet.robots.vda5050.wire import Vehicle
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.vda import official_if_here
from support.wait import wait_for

# On the embedded broker only, for now: one CI run on Mosquitto lost both vehicles' units while
# they carried their items (the adapter's session there is under investigation).
pytestmark = [pytest.mark.slow, pytest.mark.amqtt_only]

AGVS = Path(__file__).resolve().parents[1] / "vda5050_lib"
FRAME = Frame("hall")
# What vda-5050-lib's virtual pick and drop accept (its own constraints), and a short duration.
LIB_ACTIONS = {"stationType": "floor", "loadType": "EPAL", "duration": 0.5}


class LibAgvs:
    """vda-5050-lib's virtual AGVs in a Node.js process of their own."""

    def __init__(
        self,
        broker_url: str,
        agvs: dict[str, Cell],
        speed_m_s: float,
        options: dict[str, dict[str, float]] | None = None,
    ) -> None:
        """`options`: per serial number, its VirtualAgvAdapter's own (its battery's, say)."""
        spec = {
            "brokerUrl": broker_url,
            "speed": speed_m_s,
            "stateIntervalMs": 30000,
            "agvs": [
                {
                    "manufacturer": "vdalib",
                    "serialNumber": serial,
                    "x": FRAME.position(at)[0],
                    "y": FRAME.position(at)[1],
                    "mapId": FRAME.map_id,
                    "lastNodeId": node_id(at),
                    "adapterOptions": (options or {}).get(serial, {}),
                }
                for serial, at in agvs.items()
            ],
        }
        self.process = subprocess.Popen(
            ["node", str(AGVS / "agvs.mjs"), json.dumps(spec)],
            cwd=AGVS,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        ready = set()
        assert self.process.stdout is not None
        for line in self.process.stdout:  # bounded by the test's timeout
            if line.startswith("ready "):
                ready.add(line.split()[1])
            if ready == set(agvs):
                break
        assert ready == set(agvs), self.process.stderr.read() if self.process.stderr else ""

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(10)


class VdaWire:
    """Every VDA 5050 message on the broker, as it passed."""

    def __init__(self, probe: MqttProbe) -> None:
        self.seen: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        probe.client.message_callback_add("uagv/#", self._on)
        probe.subscribe("uagv/#", qos=1)

    def _on(self, client: object, userdata: object, message: Any) -> None:
        with self.lock:
            self.seen.append((message.topic, bytes(message.payload)))

    def problems(self) -> list[str]:
        """Every message's faults against the official 2.0.0 schemas (none to find without them)."""
        schemas = official_if_here()
        if schemas is None:
            return []
        found = []
        with self.lock:
            seen = list(self.seen)
        for topic, payload in seen:
            if not payload:
                continue  # a retained message cleared
            name = topic.rsplit("/", 1)[-1]
            for problem in schemas.problems("2.0.0", name, json.loads(payload)):
                found.append(f"{topic}: {problem}")
        return found


@dataclass
class LibFleet:
    """The running fleet with vda-5050-lib's vehicles, and what the test sees of it."""

    operator: OperatorPeer
    judge: Judge
    wire: VdaWire
    agvs: LibAgvs
    serials: dict[str, str]  # unit -> the vehicle's serial number

    def vehicle_states(self, unit: str) -> list[dict[str, Any]]:
        """Every state the vehicle of `unit` published, in order."""
        topic = f"uagv/v2/vdalib/{self.serials[unit]}/state"
        with self.wire.lock:
            return [json.loads(p) for t, p in self.wire.seen if t == topic]


@pytest.fixture
def agv_speed() -> float:
    """How fast vda-5050-lib's vehicles drive, in m/s (a test may parametrize it)."""
    return 0.5


@pytest.fixture
def lib_fleet(
    agv_speed: float,
    broker: BrokerThread,
    root: str,
    run_system: Callable[..., Any],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
    tmp_path: Path,
) -> Iterator[LibFleet]:
    """unit1 (2 kg) and unit2 (5 kg) of gridfleet's, vda-5050-lib's vl-1 (3 kg) at (0, 9) and
    vl-2 (4 kg) at (9, 9) as agv1 and agv2, all known to the coordinator."""
    judge = Judge()
    probe = probe_factory()
    wire = VdaWire(probe)
    probe.client.message_callback_add(
        topics.all_units("state"),
        lambda c, u, m: judge.see(m.topic.split("/")[-2], decode(UnitState, m.payload)),
    )
    probe.subscribe(topics.all_units("state"), qos=0)
    operator = OperatorPeer(probe_factory(), topics, "tester")
    path = scenario(tmp_path)
    coordinator, _ = run_system(path, step_s=STEP)
    name = root.replace("/", "-")
    serials = {"agv1": f"{name}-1", "agv2": f"{name}-2"}
    agvs = LibAgvs(
        broker.url, {serials["agv1"]: Cell(0, 9), serials["agv2"]: Cell(9, 9)}, agv_speed
    )
    configs = [
        VehicleConfig(
            Vehicle(unit, "vdalib", serial, "2.0.0"), FRAME, capacity, 0.0, True, LIB_ACTIONS
        )
        for unit, serial, capacity in (
            ("agv1", serials["agv1"], 3.0),
            ("agv2", serials["agv2"], 4.0),
        )
    ]
    from gridfleet.scenario import load_scenario

    grid = load_scenario(path).grid
    adapter = ServiceThread(
        lambda: AdapterShell(
            configs, grid, broker.url, topics, step_s=ADAPTER_STEP, schemas=official_if_here()
        ),
        "vda5050",
    ).start()
    world = coordinator.service.world
    try:
        wait_for(
            lambda: coordinator.call(lambda: sorted(world.capacities())) == [2.0, 3.0, 4.0, 5.0],
            timeout=30,
            what="the coordinator knows both units and both vehicles",
        )
        yield LibFleet(operator, judge, wire, agvs, serials)
    finally:
        operator.raw_estop(b"")
        adapter.stop()
        agvs.stop()


@pytest.mark.timeout(240)
def test_vda_5050_lib_agvs_beside_gridfleets_units_finish_every_job_safely(
    lib_fleet: LibFleet,
) -> None:
    operator, judge, wire = lib_fleet.operator, lib_fleet.judge, lib_fleet.wire
    jobs = {
        "j1": (Cell(1, 8), Cell(8, 8), 1.0),
        "j2": (Cell(8, 6), Cell(1, 1), 3.5),  # over 3 kg: agv2 (4 kg) or unit2
        "j3": (Cell(0, 6), Cell(5, 0), 2.5),
        "j4": (Cell(9, 2), Cell(4, 9), 1.5),
    }
    for job_id, (pickup, dropoff, mass) in jobs.items():
        assert operator.submit_job(pickup, dropoff, mass, job_id=job_id).accepted

    def jobs_now() -> dict[str, tuple[str, str | None, str | None]]:
        listed = operator.listed_jobs()
        return {j: (listed[j].state, listed[j].unit, listed[j].wait_reason) for j in jobs}

    wait_for(
        lambda: operator.all_final(list(jobs)),
        timeout=180,
        what="every job final",
        context=jobs_now,
    )
    listed = operator.listed_jobs()
    outcome = {j: (listed[j].state, listed[j].unit, listed[j].reason) for j in jobs}
    assert {j: listed[j].state for j in jobs} == dict.fromkeys(jobs, "done"), outcome
    by_vehicles = {j for j in jobs if listed[j].unit in ("agv1", "agv2")}
    assert by_vehicles, {j: listed[j].unit for j in jobs}
    assert judge.faults == []
    assert wire.problems() == []
    topics = {t.rsplit("/", 1)[-1] for t, _ in wire.seen}
    assert topics >= {"order", "state", "connection"}


def _agv1_job(fleet: LibFleet, pickup: Cell) -> str:
    """A 2.5 kg job from up agv1's column (too heavy for unit1; agv2 and unit2 are far)."""
    assert fleet.operator.submit_job(pickup, Cell(9, 8), 2.5, job_id="crate").accepted
    wait_for(
        lambda: any(s["driving"] for s in fleet.vehicle_states("agv1")),
        timeout=30,
        what="agv1 driving",
    )
    wait_for(
        lambda: fleet.operator.listed_jobs()["crate"].unit == "agv1",
        timeout=20,
        what="crate to agv1",
    )
    return "crate"


STOPPING_M = 0.05  # how far a vehicle may still move once it says it is paused: half a square


@pytest.mark.timeout(180)
def test_the_fleet_stop_pauses_vda_5050_lib_agvs_and_the_release_resumes_them(
    lib_fleet: LibFleet,
) -> None:
    job = _agv1_job(lib_fleet, Cell(0, 6))
    lib_fleet.operator.engage("test")
    for unit in ("agv1", "agv2"):
        wait_for(
            lambda u=unit: any(s.get("paused") for s in lib_fleet.vehicle_states(u)),
            timeout=10,
            what=f"{unit} paused",
        )
    # Measuring over a span of time: once it says it is paused, it stays (within a stopping
    # distance of the first paused position).
    time.sleep(1.5)
    states = lib_fleet.vehicle_states("agv1")
    first = next(i for i, s in enumerate(states) if s.get("paused"))
    x0, y0 = states[first]["agvPosition"]["x"], states[first]["agvPosition"]["y"]
    for later in states[first:]:
        assert later["paused"], "resumed before the release"
        moved = (
            (later["agvPosition"]["x"] - x0) ** 2 + (later["agvPosition"]["y"] - y0) ** 2
        ) ** 0.5
        assert moved <= STOPPING_M, later
    lib_fleet.operator.release("checked")
    try:
        wait_for(lambda: lib_fleet.operator.job_state(job) == "done", timeout=90, what="job done")
    except AssertionError:
        last = lib_fleet.vehicle_states("agv1")[-3:]
        raise AssertionError(
            f"{lib_fleet.operator.listed_jobs()[job]}\n{lib_fleet.operator.last_state('agv1')}\n"
            f"{json.dumps(last)[-3000:]}"
        ) from None
    assert lib_fleet.judge.faults == []


# Slow, and sent far, as test_vda5050_fleet.py's vehicle that dies (the reason is there).
@pytest.mark.parametrize("agv_speed", [DYING_SPEED_M_S], ids=["slow"])
@pytest.mark.timeout(180)
def test_killed_vda_5050_lib_agvs_are_lost_and_their_job_goes_to_a_unit(
    lib_fleet: LibFleet,
) -> None:
    job = _agv1_job(lib_fleet, FAR_PICKUP)
    lib_fleet.agvs.process.kill()  # no goodbye: the broker sends their last wills
    lib_fleet.agvs.process.wait(10)
    assert_not_at_its_pickup(lib_fleet.operator, "agv1", FAR_PICKUP)
    for unit in ("agv1", "agv2"):
        wait_for(
            lambda u=unit: lib_fleet.operator.connections(u)[-1:] == ["broken"],
            timeout=20,
            what=f"{unit} lost",
        )
    wait_for(
        lambda: lib_fleet.operator.job_state(job) == "done",
        timeout=120,
        what="job done",
        context=lambda: where(lib_fleet.operator, job, ("agv1", "unit2")),
    )
    assert lib_fleet.operator.listed_jobs()[job].unit == "unit2"
    assert lib_fleet.judge.faults == []


def test_the_node_runner_is_installed() -> None:
    # make install runs npm ci in tests/vda5050_lib: without it, the tests above cannot run.
    assert (AGVS / "node_modules" / "vda-5050-lib" / "package.json").exists(), (
        f"run 'npm ci' in {AGVS} (make install does)"
    )
    assert os.access(AGVS / "agvs.mjs", os.R_OK)
