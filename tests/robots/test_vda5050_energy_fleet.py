"""A mixed fleet on batteries: gridfleet's coordinator and its simulated units with batteries, a
vda-5050-lib 1.4.0 AGV (VDA 5050 2.0.0, Node.js) and a VDA 5050 2.1.0 vehicle of ours, all low
on charge, charging at gridfleet's chargers on the coordinator's orders (Order.charge, turned
into startCharging / stopCharging by the adapter) while jobs go on; no two units ever on one
square, every VDA 5050 message held to its official schema."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from test_vda5050_fleet import ADAPTER_STEP, FRAME, STEP, Agv, Judge, Vehicles
from test_vda5050_lib import LIB_ACTIONS, LibAgvs, VdaWire

from gridfleet.grid import Cell
from gridfleet.protocol import EnergyModel, Topics, UnitState, decode
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.wire import Vehicle
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread

from support.operator_peer import OperatorPeer
from support.paths import MAPS
from support.probe import MqttProbe
from support.vda import official_if_here
from support.wait import wait_for

pytestmark = [pytest.mark.slow, pytest.mark.amqtt_only]  # as the other VDA fleet tests

CHARGERS = {"C1": Cell(0, 4), "C2": Cell(9, 5), "C3": Cell(5, 8)}
START_PCT = 35.0  # below the coordinator's good_pct (50): idle, each goes to charge
SUFFICIENT_PCT = 80.0  # the coordinator's default: from here a charging unit takes jobs again
MOVE_PCT, CHARGE_PCT_S = 0.5, 4.0
VDA_ENERGY = EnergyModel(move_pct=MOVE_PCT, idle_pct_per_s=0.0, charge_pct_per_s=CHARGE_PCT_S)
# vda-5050-lib's battery, made to match VDA_ENERGY (test_vda5050_lib_charging.py says how).
LIB_BATTERY = {
    "initialBatteryCharge": START_PCT,
    "batteryMaxReach": FRAME.square_m * 100 / MOVE_PCT,
    "fullBatteryChargeTime": 100 / 3600 / CHARGE_PCT_S,
}
OURS = Agv("agv2", "v-2", Cell(9, 9), 3.0)


def scenario(tmp_path: Path) -> Path:
    """The playfield with unit1 (full) and unit2 (low) on batteries, and three chargers."""
    shutil.copy(MAPS / "playfield.map", tmp_path / "playfield.map")
    chargers = "".join(
        f'[[chargers]]\nname = "{name}"\nsquare = [{at.x}, {at.y}]\n'
        for name, at in CHARGERS.items()
    )
    path = tmp_path / "energy.toml"
    path.write_text(
        'name = "energy"\nmap = "playfield.map"\n'
        f"[battery]\nstart_pct = 100.0\nmove_pct = {MOVE_PCT}\nidle_pct_per_s = 0.01\n"
        f"charge_pct_per_s = {CHARGE_PCT_S}\n"
        '[[units]]\nid = "unit1"\nstart = [0, 0]\ncapacity = 2.0\n'
        '[[units]]\nid = "unit2"\nstart = [9, 0]\ncapacity = 5.0\n'
        f"battery = {{ start_pct = {START_PCT} }}\n" + chargers,
        encoding="utf-8",
    )
    return path


@dataclass
class EnergyFleet:
    """The running fleet and what the test sees of it."""

    operator: OperatorPeer
    judge: Judge
    wire: VdaWire
    vehicles: Vehicles


@pytest.fixture
def energy_fleet(
    broker: BrokerThread,
    root: str,
    run_system: Callable[..., Any],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
    tmp_path: Path,
) -> Iterator[EnergyFleet]:
    """unit1, unit2 (low), vda-5050-lib's AGV as agv1 at (0, 9) and ours as agv2 at (9, 9),
    both low, all known to the coordinator."""
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
    serial = f"{root.replace('/', '-')}-e"
    agvs = LibAgvs(broker.url, {serial: Cell(0, 9)}, 0.5, {serial: LIB_BATTERY})
    fleet = Vehicles(broker, root, load_scenario(path).grid)
    fleet.configs.append(
        VehicleConfig(
            Vehicle("agv1", "vdalib", serial, "2.0.0"),
            FRAME,
            3.0,
            0.0,
            True,
            LIB_ACTIONS,
            energy=VDA_ENERGY,
        )
    )
    stations = tuple(FRAME.position(at) for at in CHARGERS.values())
    fleet.add(
        OURS,
        energy=VDA_ENERGY,
        battery_pct=START_PCT,
        node_pct=MOVE_PCT,
        idle_pct_per_s=0.0,
        charge_pct_per_s=CHARGE_PCT_S,
        chargers=stations,  # it charges only on a charging station: gridfleet's chargers
        state_every_s=ADAPTER_STEP,
    )
    fleet.start()
    world = coordinator.service.world
    try:
        wait_for(
            lambda: coordinator.call(lambda: sorted(world.capacities())) == [2.0, 3.0, 3.0, 5.0],
            timeout=30,
            what="the coordinator knows both units and both vehicles",
        )
        yield EnergyFleet(operator, judge, wire, fleet)
    finally:
        operator.raw_estop(b"")
        fleet.stop()
        agvs.stop()


def charged_at_a_charger(operator: OperatorPeer, unit: str) -> list[UnitState]:
    """The states of `unit` charging, each on one of the chargers."""
    return [
        s for s in operator.states(unit) if s.charging and Cell(*s.position) in CHARGERS.values()
    ]


@pytest.mark.timeout(240)
def test_vda_5050_vehicles_low_on_charge_charge_at_gridfleets_chargers_beside_its_units(
    energy_fleet: EnergyFleet,
) -> None:
    operator, judge = energy_fleet.operator, energy_fleet.judge
    jobs = {"j1": (Cell(1, 1), Cell(8, 1), 1.0), "j2": (Cell(1, 6), Cell(4, 9), 1.5)}
    for job_id, (pickup, dropoff, mass) in jobs.items():
        assert operator.submit_job(pickup, dropoff, mass, job_id=job_id).accepted

    def battery() -> dict[str, tuple[float | None, bool, tuple[int, int]] | None]:
        out: dict[str, tuple[float | None, bool, tuple[int, int]] | None] = {}
        for unit in ("unit1", "unit2", "agv1", "agv2"):
            last = operator.last_state(unit)
            out[unit] = None if last is None else (last.battery_pct, last.charging, last.position)
        return out

    for unit in ("agv1", "agv2", "unit2"):
        wait_for(
            lambda u=unit: charged_at_a_charger(operator, u),
            timeout=60,
            what=f"{unit} charging at a charger",
            context=battery,
        )
    for unit in ("agv1", "agv2"):
        wait_for(
            lambda u=unit: max((s.battery_pct or 0) for s in operator.states(u)) >= SUFFICIENT_PCT,
            timeout=90,
            what=f"{unit} charged to {SUFFICIENT_PCT} %",
            context=battery,
        )
    wait_for(lambda: operator.all_final(list(jobs)), timeout=120, what="both jobs final")
    listed = operator.listed_jobs()
    assert {j: listed[j].state for j in jobs} == dict.fromkeys(jobs, "done")
    # Two units never on one square, chargers included.
    assert judge.faults == [] and judge.seen > 50
    # What the vehicles were told: a start at their chargers, never an order they refused.
    ours = energy_fleet.vehicles.virtual["agv2"]
    told = [
        a["actionType"]
        for name, m in ours.received
        if name == "instantActions"
        for a in m["actions"]
    ]
    assert "startCharging" in told
    refusals = [
        e
        for name, m in ours.sent
        if name == "state"
        for e in m["errors"]
        if e["errorType"] in ("orderError", "chargingError")
    ]
    assert refusals == []
    schemas = official_if_here()
    with energy_fleet.wire.lock:
        lib = [(t, json.loads(p)) for t, p in energy_fleet.wire.seen if "/vdalib/" in t and p]
    for topic, message in lib if schemas is not None else []:  # the 2.0.0 AGV's, both ways
        assert schemas.problems("2.0.0", topic.rsplit("/", 1)[-1], message) == [], topic
    for name, message in [*ours.received, *ours.sent] if schemas is not None else []:
        assert schemas.problems("2.1.0", name, message) == [], (name, message)
