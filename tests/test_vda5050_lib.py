"""VDA 5050 2.0.0 vehicles nobody here wrote: `vda-5050-lib`'s virtual AGVs (1.4.0, its
AgvController and VirtualAgvAdapter, in Node.js) beside gridfleet's units, under one planner and
one stop; every VDA 5050 message of the run, both ways, held to the official 2.0.0 schemas."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from test_vda5050_fleet import STEP, Judge, scenario

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
from support.vda import needs_schemas, official
from support.wait import wait_for

pytestmark = [pytest.mark.slow, needs_schemas]

AGVS = Path(__file__).resolve().parent / "vda5050_lib"
FRAME = Frame("hall")
# What vda-5050-lib's virtual pick and drop accept (its own constraints), and a short duration.
LIB_ACTIONS = {"stationType": "floor", "loadType": "EPAL", "duration": 0.5}


class LibAgvs:
    """vda-5050-lib's virtual AGVs in a Node.js process of their own."""

    def __init__(self, broker_url: str, agvs: dict[str, Cell]) -> None:
        spec = {
            "brokerUrl": broker_url,
            "speed": 0.5,
            "stateIntervalMs": 30000,
            "agvs": [
                {
                    "manufacturer": "vdalib",
                    "serialNumber": serial,
                    "x": FRAME.position(at)[0],
                    "y": FRAME.position(at)[1],
                    "mapId": FRAME.map_id,
                    "lastNodeId": node_id(at),
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
        schemas = official()
        found = []
        with self.lock:
            seen = list(self.seen)
        for topic, payload in seen:
            if not payload:
                continue  # a retained message cleared
            name = topic.rsplit("/", 1)[-1]
            for problem in schemas.problems("2.0.0", name, json.loads(payload)):  # type: ignore[arg-type]
                found.append(f"{topic}: {problem}")
        return found


@pytest.fixture
def lib_fleet(
    broker: BrokerThread,
    root: str,
    run_system: Callable[..., Any],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
    tmp_path: Path,
) -> Iterator[tuple[OperatorPeer, Judge, VdaWire, ServiceThread[Any]]]:
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
    agvs = LibAgvs(
        broker.url,
        {f"{root.replace('/', '-')}-1": Cell(0, 9), f"{root.replace('/', '-')}-2": Cell(9, 9)},
    )
    serials = [a["serialNumber"] for a in json.loads(agvs.process.args[2])["agvs"]]  # type: ignore[index]
    configs = [
        VehicleConfig(
            Vehicle(unit, "vdalib", serial, "2.0.0"), FRAME, capacity, 0.0, True, LIB_ACTIONS
        )
        for unit, serial, capacity in (("agv1", serials[0], 3.0), ("agv2", serials[1], 4.0))
    ]
    from gridfleet.scenario import load_scenario

    grid = load_scenario(path).grid
    adapter = ServiceThread(
        lambda: AdapterShell(configs, grid, broker.url, topics, step_s=STEP, schemas=official()),
        "vda5050",
    ).start()
    world = coordinator.service.world
    try:
        wait_for(
            lambda: coordinator.call(lambda: sorted(world.capacities())) == [2.0, 3.0, 4.0, 5.0],
            timeout=30,
            what="the coordinator knows both units and both vehicles",
        )
        yield operator, judge, wire, coordinator
    finally:
        operator.raw_estop(b"")
        adapter.stop()
        agvs.stop()


@pytest.mark.timeout(240)
def test_vda_5050_lib_agvs_beside_gridfleets_units_finish_every_job_safely(
    lib_fleet: tuple[OperatorPeer, Judge, VdaWire, ServiceThread[Any]],
) -> None:
    operator, judge, wire, _ = lib_fleet
    jobs = {
        "j1": (Cell(1, 8), Cell(8, 8), 1.0),
        "j2": (Cell(8, 6), Cell(1, 1), 3.5),  # over 3 kg: agv2 (4 kg) or unit2
        "j3": (Cell(0, 6), Cell(5, 0), 2.5),
        "j4": (Cell(9, 2), Cell(4, 9), 1.5),
    }
    for job_id, (pickup, dropoff, mass) in jobs.items():
        assert operator.submit_job(pickup, dropoff, mass, job_id=job_id).accepted
    wait_for(lambda: operator.all_final(list(jobs)), timeout=180, what="every job final")
    listed = operator.listed_jobs()
    assert {j: listed[j].state for j in jobs} == dict.fromkeys(jobs, "done"), listed
    by_vehicles = {j for j in jobs if listed[j].unit in ("agv1", "agv2")}
    assert by_vehicles, {j: listed[j].unit for j in jobs}
    assert judge.faults == []
    assert wire.problems() == []
    topics = {t.rsplit("/", 1)[-1] for t, _ in wire.seen}
    assert topics >= {"order", "state", "connection"}


def test_the_node_runner_is_installed() -> None:
    # make install runs npm ci in tests/vda5050_lib: without it, the tests above cannot run.
    assert (AGVS / "node_modules" / "vda-5050-lib" / "package.json").exists(), (
        f"run 'npm ci' in {AGVS} (make install does)"
    )
    assert os.access(AGVS / "agvs.mjs", os.R_OK)
