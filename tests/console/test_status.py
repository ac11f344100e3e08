"""`gridfleet status`: the fleet at a glance, drawn from the retained topics."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from gridfleet.console.status import CLEAR, FleetStatus, render, unit_lines
from gridfleet.grid import Cell
from gridfleet.protocol import (
    ChargerView,
    Connection,
    CoordinatorStatus,
    EnergyView,
    JobsView,
    JobView,
    Leds,
    Routes,
    RouteView,
    Sensors,
    Thresholds,
    Topics,
    UnitEnergy,
    UnitState,
    encode,
)
from gridfleet.protocol.messages import JobState, Message
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.cli import gridfleet
from support.effects import header
from support.output import Output
from support.probe import MqttProbe
from support.wait import wait_for

T = Topics("fleet")
FREE = Sensors(N="free", E="free", S="free", W="free")


def state(unit: str, x: int, y: int, **fields: Any) -> UnitState:
    values: dict[str, Any] = {"status": "idle", "direction": "-", "leds": Leds(), **fields}
    return UnitState(header=header(unit), step=7, position=Cell(x, y), sensors=FREE, **values)


def job(job_id: str, state: JobState, unit: str | None = None, **fields: Any) -> JobView:
    return JobView(
        id=job_id, pickup=Cell(1, 1), dropoff=Cell(8, 8), mass_kg=1.5, state=state, unit=unit,
        **fields,
    )  # fmt: skip


def fed(*messages: tuple[str, Message | bytes | str]) -> FleetStatus:
    """A FleetStatus that read `messages` (topic, message or raw payload), as from the broker."""
    fleet = FleetStatus()
    for topic, message in messages:
        payload = (
            message.encode() if isinstance(message, str)
            else message if isinstance(message, bytes)
            else encode(message)
        )  # fmt: skip
        kind, source = T.parse(topic)
        fleet.apply(kind, source, topic, payload)
    return fleet


def online(step: int = 1234, **fields: Any) -> tuple[str, CoordinatorStatus]:
    status = CoordinatorStatus(
        header=header("coordinator"), state="online", step=step, step_period_s=0.2, **fields
    )
    return T.fleet("coordinator"), status


def test_a_running_fleet_in_lines() -> None:
    fleet = fed(
        online(achieved_step_s=0.213),
        (T.unit("connection", "unit1"), Connection(header=header("unit1"), state="online")),
        (T.unit("connection", "unit2"), Connection(header=header("unit2"), state="broken")),
        (T.unit("state", "unit1"), state("unit1", 3, 1, status="moving", job_id="crate",
                                         load_kg=1.5)),
        (T.unit("state", "unit2"), state("unit2", 10, 5, status="waiting",
                                         wait_reason="released square [5, 1] is blocked")),
        (T.fleet("routes"), Routes(header=header("coordinator"), step=3, routes={
            "unit1": RouteView(), "unit2": RouteView(control="out_of_service")})),
        (T.fleet("jobs"), JobsView(header=header("coordinator"), jobs=[
            job("crate", "to_dropoff", "unit1"),
            job("old", "done", "unit1"),
            job("big", "rejected", reason="too heavy"),
            job("next", "queued", wait="no_unit_free",
                wait_reason="every unit that can carry 1.5 kg is busy (unit1)"),
        ])),
    )  # fmt: skip
    assert render(fleet) == [
        "stop: clear",
        "coordinator: online, step 1234, a step every 0.2 s, achieved 0.21 s",
        "",
        "units: 2, 1 online",
        "  unit   connection  square  status                   job    load kg  waiting for",
        "  unit1  online      3,1     moving                   crate  1.5",
        "  unit2  broken      10,5    waiting, out of service  -      0        released square "
        "[5, 1] is blocked",
        "",
        "jobs: 1 queued, 1 to_dropoff, 1 done, 1 rejected",
        "  job    state       unit   waiting for",
        "  crate  to_dropoff  unit1",
        "  next   queued      -      every unit that can carry 1.5 kg is busy (unit1)",
    ]


def test_the_stop_says_who_holds_the_fleet() -> None:
    latch = T.fleet("estop")
    press = T.unit("stop", "unit2")
    button = T.device("device_stop", "device-unit1")
    assert render(fed((latch, "released|dashboard|checked")))[0] == "stop: clear"
    assert render(fed((latch, "engaged|dashboard|operator pressed STOP")))[0] == (
        "stop: ENGAGED, latched by dashboard (operator pressed STOP)"
    )
    pressed = fed(
        (latch, "released|dashboard|"),
        (press, "engaged|unit2|bumper hit"),
        (button, "engaged|device-unit1|button"),
    )
    assert render(pressed)[0] == (
        "stop: ENGAGED, pressed by device-unit1 (button), unit2 (bumper hit)"
    )
    both = fed((latch, "engaged|unit2|bumper hit"), (press, "engaged|unit2|bumper hit"))
    assert render(both)[0] == (
        "stop: ENGAGED, latched by unit2 (bumper hit); pressed by unit2 (bumper hit)"
    )
    cleared = fed((latch, "engaged|ann|"), (press, "engaged|unit2|x"), (latch, ""), (press, ""))
    assert render(cleared)[0] == "stop: clear"  # `gridfleet clean` empties them
    said = fed(online(estop=True))
    assert render(said)[0] == (
        "stop: ENGAGED (so says the coordinator; its latch is not on the broker yet)"
    )


def test_a_coordinator_that_is_not_running_and_an_empty_root() -> None:
    offline = CoordinatorStatus(header=header("coordinator"), state="offline", step=88)
    broken = CoordinatorStatus(header=header("coordinator"), state="broken")
    assert render(fed((T.fleet("coordinator"), offline)))[1] == (
        "coordinator: offline (stopped at step 88)"
    )
    assert render(fed((T.fleet("coordinator"), broken)))[1] == (
        "coordinator: broken (gone without saying goodbye)"
    )
    assert render(FleetStatus()) == [
        "stop: clear",
        "coordinator: no status on the broker (has one ever run under this root?)",
        "",
        "units: none on the broker",
        "",
        "jobs: no job queue on the broker",
    ]
    empty = fed((T.fleet("jobs"), JobsView(header=header("coordinator"), jobs=[])))
    assert render(empty)[-1] == "jobs: none"


def test_a_unit_known_only_by_its_connection_and_a_long_queue() -> None:
    jobs = [job(f"j{n:02}", "queued") for n in range(25)]
    fleet = fed(
        (T.unit("connection", "u9"), Connection(header=header("u9"), state="offline")),
        (T.fleet("jobs"), JobsView(header=header("coordinator"), jobs=jobs)),
    )
    lines = render(fleet, most_jobs=3)
    assert lines[3:6] == [
        "units: 1, 0 online",
        "  unit  connection  square  status  job  load kg  waiting for",
        "  u9    offline     -       -       -    -",
    ]
    assert lines[7:] == [
        "jobs: 25 queued",
        "  job  state   unit  waiting for",
        "  j00  queued  -",
        "  j01  queued  -",
        "  j02  queued  -",
        "  ... and 22 more not final",
    ]


def status(*args: str) -> subprocess.CompletedProcess[str]:
    return gridfleet("status", *args)


def test_status_once_on_the_real_system(
    broker: BrokerThread,
    root: str,
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    probe_factory: Callable[..., MqttProbe],
    playfield: Path,
) -> None:
    run_system(playfield)
    topics = Topics(root)
    probe = probe_factory()
    probe.subscribe(topics.all_units("state"), qos=0)
    units = ("unit1", "unit2", "unit3", "unit4")
    wait_for(
        lambda: all(probe.received(topics.unit("state", u)) for u in units), what="every state"
    )
    probe.publish(topics.fleet("estop"), "engaged|ann|spill in aisle 3", retain=True)
    wait_for(
        lambda: "latched by ann" in status("--once", "--broker", broker.url, "--root", root).stdout,
        timeout=10,
        interval=0.2,
        what="the stop in the status",
    )
    out = status("--once", "--broker", broker.url, "--root", root)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == f"broker: {broker.url}"  # the one it reached
    assert lines[1] == "stop: ENGAGED, latched by ann (spill in aisle 3)"
    assert lines[2].startswith("coordinator: online, step ")
    assert lines[4] == "units: 4, 4 online"
    for unit in units:
        assert any(line.split()[:2] == [unit, "online"] for line in lines), out.stdout
    assert lines[-1] == "jobs: none"
    probe.publish(topics.fleet("estop"), "released|ann|", retain=True)


def test_status_once_without_a_coordinator_is_one_line(broker: BrokerThread, root: str) -> None:
    out = status("--once", "--broker", broker.url, "--root", root, "--timeout", "1")
    assert (out.returncode, out.stdout) == (2, "")
    assert out.stderr.splitlines() == [
        f"gridfleet status: error: nothing from the coordinator on {broker.url} under root "
        f"{root!r} within 1 s: is it running?"
    ]


def test_status_redraws_until_ctrl_c(broker: BrokerThread, root: str) -> None:
    watching = subprocess.Popen(
        [sys.executable, "-m", "gridfleet", "status", "--broker", broker.url, "--root", root],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    output = Output(watching)
    try:
        # Two drawings (a second apart) before the Ctrl-C; CI saw a fixed 3.5 s fall short.
        wait_for(lambda: output.text.count("(Ctrl-C to quit)") >= 2, 30, what="two drawings")
    finally:
        os.kill(watching.pid, signal.SIGINT)
        watching.wait(timeout=20)
        output.wait_closed()
    out = output.text
    assert watching.returncode == 0, out[-2000:]
    drawings = out.split(CLEAR)[1:]
    assert len(drawings) >= 2, out
    assert drawings[-1].splitlines()[1:4] == [
        "(Ctrl-C to quit)",
        "",
        "stop: clear",
    ]
    assert drawings[-1].startswith(f"gridfleet status: {broker.url}, root {root!r}, ")


@pytest.mark.parametrize("timeout", ["0", "-1", "nan"])
def test_a_bad_timeout_is_one_line(timeout: str) -> None:
    out = status("--once", "--timeout", timeout)
    assert out.returncode == 2
    assert out.stderr.splitlines() == [
        f"gridfleet status: error: --timeout {float(timeout):g}: give a positive number of seconds"
    ]


def test_a_vda_5050_vehicle_says_so_beside_its_connection() -> None:
    from gridfleet.protocol import Factsheet

    sheet = Factsheet(
        header=header("agv1"), capacity_kg=3.0, step_period_s=0.5, sensors=[], model="vda5050-2.1.0"
    )
    fleet = fed(
        (T.unit("connection", "agv1"), Connection(header=header("agv1"), state="online")),
        (T.unit("factsheet", "agv1"), sheet),
        (T.unit("state", "agv1"), state("agv1", 0, 9)),
    )
    lines = unit_lines(fleet)
    assert lines[0] == "units: 1, 1 online"
    assert "online (VDA 5050 2.1.0)" in lines[2]
    fleet.apply("factsheet", "agv1", T.unit("factsheet", "agv1"), b"")  # cleared
    assert "VDA" not in unit_lines(fleet)[2]


def test_a_vda_5050_vehicle_shows_its_battery_and_its_own_errors() -> None:
    from gridfleet.protocol import VehicleCondition

    condition = VehicleCondition(
        header=header("agv1"),
        battery_pct=41.6,
        charging=True,
        errors=["FATAL motorFault: left wheel", "WARNING lowBattery"],
    )
    fleet = fed(
        (T.unit("connection", "agv1"), Connection(header=header("agv1"), state="broken")),
        (T.unit("vehicle", "agv1"), condition),
    )
    (row,) = unit_lines(fleet)[2:]
    assert "broken, battery 42 % charging" in row
    assert row.endswith("vehicle: FATAL motorFault: left wheel; WARNING lowBattery")
    fleet.apply("vehicle", "agv1", T.unit("vehicle", "agv1"), b"")  # cleared
    assert "battery" not in unit_lines(fleet)[2]


def test_batteries_plans_and_chargers_in_lines() -> None:
    # The battery column comes with the first unit that reports one; a unit without shows "-".
    thresholds = Thresholds(critical_pct=20, good_pct=50, sufficient_pct=80, full_pct=95)
    energy = EnergyView(
        header=header("coordinator"),
        thresholds=thresholds,
        chargers=[
            ChargerView(name="C1", square=Cell(0, 0), unit="unit1", queue=["unit3"]),
            ChargerView(name="C2", square=Cell(9, 0), unit="unit2"),
            ChargerView(name="C3", square=Cell(9, 9)),
        ],
        units={
            "unit1": UnitEnergy(plan="charging", charger="C1", reason="charging: 62 % of 80 %"),
            "unit2": UnitEnergy(plan="to_charger", charger="C2"),
            "unit3": UnitEnergy(plan="queued", charger="C1"),
            "unit4": UnitEnergy(plan="stranded"),
        },
    )
    fleet = fed(
        (T.unit("state", "unit1"), state("unit1", 0, 0, battery_pct=61.6, charging=True)),
        (T.unit("state", "unit2"), state("unit2", 4, 4, status="moving", battery_pct=38.0)),
        (T.unit("state", "unit3"), state("unit3", 0, 9, status="waiting", battery_pct=19.0,
                                         wait_reason="waiting for charger C1")),
        (T.unit("state", "unit4"), state("unit4", 9, 8, battery_pct=3.0)),
        (T.unit("state", "unit5"), state("unit5", 5, 5)),
        (T.fleet("energy"), energy),
    )  # fmt: skip
    assert unit_lines(fleet) == [
        "units: 5, 0 online",
        "  unit   connection  square  status   job  load kg  battery        waiting for",
        "  unit1  -           0,0     idle     -    0        62 % charging  charging: 62 % of 80 %",
        "  unit2  -           4,4     moving   -    0        38 %           to charger C2",
        "  unit3  -           0,9     waiting  -    0        19 %           waiting for charger C1",
        "  unit4  -           9,8     idle     -    0        3 %            stranded: it cannot "
        "reach a charger",
        "  unit5  -           5,5     idle     -    0        -",
    ]  # the plan said once when the unit says it too (unit3)
    lines = render(fleet)
    at = lines.index("chargers: 3 (critical 20 %, good 50 %, sufficient 80 %, full 95 %)")
    assert lines[at + 1 : at + 6] == [
        "  charger  square  unit              queue",
        "  C1       0,0     unit1 charging    unit3",
        "  C2       9,0     unit2 on its way  -",
        "  C3       9,9     free              -",
        "",
    ]
    # A fleet without energy: no battery column, no chargers (as before 1.5).
    plain = fed((T.unit("state", "unit5"), state("unit5", 5, 5)))
    assert "battery" not in unit_lines(plain)[1]
    assert not any(line.startswith("chargers") for line in render(plain))
    # The view cleared (`gridfleet clean`): its chargers go.
    cleared = fed((T.fleet("energy"), energy), (T.fleet("energy"), b""))
    assert cleared.energy is None


def test_a_plan_says_where_then_why_unless_its_reason_says_both() -> None:
    from gridfleet.console.status import plan_words
    from gridfleet.protocol import UnitEnergy

    sent = UnitEnergy(plan="to_charger", charger="C1", reason="below good 50 %; charges up to 80 %")
    assert plan_words(sent) == "to charger C1: below good 50 %; charges up to 80 %"
    assert plan_words(
        UnitEnergy(plan="charging", charger="C1", reason="charging: 62 % of 80 %")
    ) == ("charging: 62 % of 80 %")
    assert plan_words(UnitEnergy(plan="queued", charger="C2")) == "waiting for charger C2"
    assert plan_words(UnitEnergy(plan="stranded")) == "stranded: it cannot reach a charger"
    far = UnitEnergy(plan="stranded", reason="no charger can be reached from [3, 3]")
    assert plan_words(far) == "stranded: no charger can be reached from [3, 3]"
