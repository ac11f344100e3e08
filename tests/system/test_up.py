"""`gridfleet up` brings the whole system up, and Ctrl-C leaves nothing running."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from gridfleet.grid import Cell
from gridfleet.protocol import Connection, Topics, decode
from gridfleet.system.broker_thread import BrokerThread

from support.cli import gridfleet
from support.output import Output, alive
from support.probe import MqttProbe
from support.wait import wait_for

pytestmark = pytest.mark.slow


def started_up(*args: str) -> tuple[subprocess.Popen[str], Output]:
    """`gridfleet up ARGS`, once it says it is running (its output read as it comes)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "gridfleet", "up", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    out = Output(proc)
    try:
        out.wait(r"gridfleet is running: open http://127\.0\.0\.1:\d+", timeout=90)
    except BaseException:
        proc.kill()
        proc.wait(30)
        raise
    return proc, out


@pytest.mark.timeout(240)  # its waits (start 90 s, stop 60 s) are the limits that matter
def test_up_runs_everything_and_ctrl_c_stops_it_cleanly(
    broker: BrokerThread,
    root: str,
    tmp_path: Path,
    probe_factory: Callable[..., MqttProbe],
    playfield: Path,
) -> None:
    topics = Topics(root)
    proc, out = started_up(
        "--broker", broker.url, "--broker-ws", broker.ws_url, "--root", root, "--port", "0",
        "--step", "0.05", "--db", str(tmp_path / "jobs.db"), "--scenario", str(playfield),
    )  # fmt: skip
    try:
        probe = probe_factory()
        probe.subscribe(topics.all_units("state"), qos=0)
        # Every unit of the playfield is online and moving through the real components.
        for unit in ("unit1", "unit2", "unit3", "unit4"):
            probe.wait(topics.unit("state", unit), timeout=30)
        probe.subscribe(topics.fleet("jobs"))
        # The scenario's jobs, tagged with this run (the job store outlives runs: ids must not
        # clash with the last run's).
        tagged = re.compile(rb'"playfield-\d{6}-job-1"')
        probe.wait(topics.fleet("jobs"), lambda m: tagged.search(m.payload) is not None, timeout=30)
        pids = [int(p) for p in re.findall(r"started \(pid (\d+)\)", out.text)]
        assert len(pids) >= 4
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    assert proc.returncode == 0, out.text[-3000:]
    out.wait(r"\[coordinator *\] stopped", timeout=10)  # stopped last: the reader has it all
    assert "Traceback" not in out.text
    # Each component left cleanly when asked to (the dashboard on SIGTERM too).
    stops = dict(re.findall(r"^\[(\w+) *\] stopped \(code (-?\d+)\)$", out.text, re.M))
    assert {"coordinator", "robots", "dashboard"} <= set(stops), out.text[-3000:]
    # The operator too, when stopped mid-submission.
    assert set(stops.values()) == {"0"}, out.text[-3000:]
    wait_for(lambda: not any(alive(p) for p in pids), 10, what="every component to exit")
    # Each unit said "offline" on its way out.
    checker = probe_factory()
    checker.subscribe(topics.all_units("connection"))
    for unit in ("unit1", "unit2", "unit3", "unit4"):
        seen = checker.wait(topics.unit("connection", unit))
        assert decode(Connection, seen.payload).state == "offline"


def test_up_with_a_busy_broker_port_says_so_at_once_and_leaves_nothing(
    broker: BrokerThread,
) -> None:
    out = subprocess.run(
        [
            sys.executable, "-m", "gridfleet", "up", "--mqtt-port", str(broker.port),
            "--ws-port", "0", "--port", "0",
        ],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert out.returncode == 2, out.stdout[-2000:] + out.stderr
    assert "Traceback" not in out.stdout + out.stderr and "restarting" not in out.stdout
    assert "broker did not start" in out.stderr and f"port {broker.port}" in out.stderr
    pids = [int(p) for p in re.findall(r"started \(pid (\d+)\)", out.stdout)]
    assert pids and not any(alive(p) for p in pids)


def test_up_refuses_a_bad_step_before_starting_anything() -> None:
    out = gridfleet("up", "--step", "-1", "--mqtt-port", "0")
    assert out.returncode == 2 and "started" not in out.stdout
    assert out.stderr.strip() == (
        "gridfleet up: error: --step -1: the step period must be in (0, 60] seconds"
    )


def test_up_refuses_a_bad_unit_process_count_before_starting_anything() -> None:
    out = gridfleet("up", "--workers", "0", "--mqtt-port", "0")
    assert out.returncode == 2 and "started" not in out.stdout
    assert out.stderr.strip() == "gridfleet up: error: --workers 0: give at least 1"


def _up(broker: BrokerThread, root: str, tmp_path: Path, playfield: Path) -> subprocess.Popen[str]:
    """`gridfleet up` on the test's broker, its output on a pipe."""
    return subprocess.Popen(
        [
            sys.executable, "-m", "gridfleet", "up", "--broker", broker.url,
            "--broker-ws", broker.ws_url, "--root", root, "--port", "0", "--step", "0.05",
            "--db", str(tmp_path / "jobs.db"), "--scenario", str(playfield),
        ],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip


def _running(proc: subprocess.Popen[str]) -> tuple[list[int], str]:
    """Read `up`'s output until it says it is running: the components' pids and that output."""
    assert proc.stdout is not None
    lines: list[str] = []
    for line in iter(proc.stdout.readline, ""):  # bounded by the test's timeout
        lines.append(line)
        if "gridfleet is running" in line:
            break
    text = "".join(lines)
    pids = [int(p) for p in re.findall(r"started \(pid (\d+)\)", text)]
    assert len(pids) >= 4, text[-3000:]
    return pids, text


@pytest.mark.timeout(180)
def test_up_killed_with_sigkill_leaves_no_component_running(
    broker: BrokerThread, root: str, tmp_path: Path, playfield: Path
) -> None:
    proc = _up(broker, root, tmp_path, playfield)
    pids, _ = _running(proc)
    proc.kill()  # nothing of `up` runs after this: the components must notice on their own
    proc.wait(timeout=10)
    wait_for(lambda: not any(alive(p) for p in pids), 30, what="every component to exit")


@pytest.mark.timeout(180)
def test_up_stops_everything_on_sighup(
    broker: BrokerThread, root: str, tmp_path: Path, playfield: Path
) -> None:
    proc = _up(broker, root, tmp_path, playfield)
    pids, _ = _running(proc)
    out = Output(proc)
    proc.send_signal(signal.SIGHUP)  # the terminal was closed
    assert proc.wait(timeout=60) == 0, out.text[-3000:]
    assert "Traceback" not in out.text
    wait_for(lambda: not any(alive(p) for p in pids), 10, what="every component to exit")


@pytest.mark.timeout(180)
def test_up_stops_everything_when_its_output_is_closed(
    broker: BrokerThread, root: str, tmp_path: Path, playfield: Path
) -> None:
    proc = _up(broker, root, tmp_path, playfield)  # as in `gridfleet up | head`
    pids, _ = _running(proc)
    assert proc.stdout is not None
    proc.stdout.close()  # the reader is gone; the next line `up` writes finds the pipe closed
    assert proc.wait(timeout=60) == 0
    wait_for(lambda: not any(alive(p) for p in pids), 10, what="every component to exit")


@pytest.mark.timeout(180)
def test_up_without_robots_runs_the_rest_for_units_that_join_from_elsewhere(
    broker: BrokerThread, root: str, tmp_path: Path, playfield: Path
) -> None:
    # Webots units (robots/webots/README.md) or real ones take the scenario's ids: a simulated
    # unit1 beside them would be a second unit1.
    proc, out = started_up(
        "--no-robots", "--broker", broker.url, "--broker-ws", broker.ws_url, "--root", root,
        "--port", "0", "--step", "0.2", "--db", str(tmp_path / "jobs.db"),
        "--scenario", str(playfield),
    )  # fmt: skip
    try:
        started = set(re.findall(r"^\[(\w+) *\] started", out.text, re.M))
        assert {"coordinator", "dashboard"} <= started and "robots" not in started, out.text
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    assert proc.returncode == 0, out.text[-3000:]
    assert "[robots" not in out.text


VEHICLES = """
[maps.hall]
[[vehicles]]
unit = "agv1"
manufacturer = "gridfleet"
serial_number = "{serial}"
version = "2.1.0"
map = "hall"
"""


@pytest.mark.timeout(180)
def test_up_with_vehicles_runs_the_vda5050_adapter_and_a_vehicle_joins_as_a_unit(
    broker: BrokerThread,
    root: str,
    tmp_path: Path,
    probe_factory: Callable[..., MqttProbe],
    playfield: Path,
) -> None:
    from gridfleet.robots.vda5050.frame import Frame
    from gridfleet.robots.vda5050.virtual import VirtualSpec
    from gridfleet.robots.vda5050.virtual_shell import VirtualVehicleShell
    from gridfleet.robots.vda5050.wire import Vehicle
    from gridfleet.system.threads import ServiceThread

    topics = Topics(root)
    serial = root.replace("/", "-")
    vehicles = tmp_path / "vehicles.toml"
    vehicles.write_text(VEHICLES.format(serial=serial), encoding="utf-8")
    frame = Frame("hall")
    shell = VirtualVehicleShell(
        Vehicle("agv1", "gridfleet", serial, "2.1.0"),
        VirtualSpec(frame.position(Cell(5, 0)), "hall", capacity_kg=3.0),
        broker.url,
    )
    probe = probe_factory()
    probe.subscribe(topics.unit("connection", "agv1"))
    with ServiceThread(lambda: shell, "vehicle"):
        proc, out = started_up(
            "--no-robots", "--vehicles", str(vehicles), "--broker", broker.url,
            "--broker-ws", broker.ws_url, "--root", root, "--port", "0", "--step", "0.2",
            "--db", str(tmp_path / "jobs.db"), "--scenario", str(playfield),
        )  # fmt: skip
        try:
            assert re.search(r"^\[vda5050 *\] started", out.text, re.M), out.text
            wait_for(
                lambda: [decode(Connection, m.payload).state for m in
                         probe.received(topics.unit("connection", "agv1"))][-1:] == ["online"],
                timeout=30, what="agv1 online through the adapter",
            )  # fmt: skip
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=60)
    assert proc.returncode == 0, out.text[-3000:]
    states = [
        decode(Connection, m.payload).state
        for m in probe.received(topics.unit("connection", "agv1"))
    ]
    assert states[-1] == "offline"  # the adapter said goodbye for it


def test_up_refuses_vehicles_with_accounts_without_the_adapters_account(
    tmp_path: Path, playfield: Path
) -> None:
    from gridfleet.accounts import VehicleLink, default_accounts, write_accounts
    from gridfleet.scenario import load_scenario

    vehicles = tmp_path / "vehicles.toml"
    vehicles.write_text(VEHICLES.format(serial="s1"), encoding="utf-8")
    units = [u.id for u in load_scenario(playfield).units]
    accounts = tmp_path / "accounts.toml"

    def up_says(links: list[VehicleLink]) -> str:
        write_accounts(default_accounts(units, links), accounts)
        out = subprocess.run(
            [sys.executable, "-m", "gridfleet", "up", "--vehicles", str(vehicles),
             "--accounts", str(accounts), "--scenario", str(playfield), "--mqtt-port", "0"],
            capture_output=True, text=True, timeout=60, check=False,
        )  # fmt: skip
        assert out.returncode == 2 and "started" not in out.stdout
        assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr
        return out.stderr

    assert (
        f"no vda5050 account, which --vehicles needs: gridfleet accounts add vda5050 --role "
        f"vda5050 --vehicles {vehicles} --file {accounts}"
    ) in up_says([])
    other = up_says([VehicleLink("agv1", "uagv/v2/gridfleet/another")])
    assert "account vda5050 does not speak for vehicle agv1" in other
    assert '{ unit = "agv1", topic = "uagv/v2/gridfleet/s1" }' in other
