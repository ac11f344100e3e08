"""A units process killed mid-job resumes where its units stood, with what they carried
(`gridfleet robots --state FILE`) and the charge their batteries had, and the job completes;
bad state files are refused."""

from __future__ import annotations

import signal
import sqlite3
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from gridfleet.bench.system.scenario import make_scenario
from gridfleet.energy import BatterySpec
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import Topics
from gridfleet.robots.fleet import Fleet
from gridfleet.robots.saved import Saved, SavedUnits
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, coordinator_thread

from support.operator_peer import OperatorPeer
from support.paths import MAPS
from support.probe import MqttProbe
from support.wait import wait_for

PLAYFIELD = MAPS / "playfield.toml"
STEP_S = 0.05


def robots(url: str, root: str, state: Path) -> subprocess.Popen[bytes]:
    """`gridfleet robots` for the playfield, saving to `state`."""
    argv = ["robots", "--broker", url, "--root", root, "--scenario", str(PLAYFIELD)]
    argv += ["--step", str(STEP_S), "--state", str(state)]
    return subprocess.Popen([sys.executable, "-m", "gridfleet", *argv], stderr=subprocess.PIPE)


@pytest.fixture
def coordinator(broker: BrokerThread, root: str, tmp_path: Path) -> Iterator[ServiceThread]:
    thread = coordinator_thread(
        load_scenario(PLAYFIELD), broker.url, root=root, step_s=STEP_S, db_path=tmp_path / "j.db"
    ).start(30)
    yield thread
    thread.stop(30)


@pytest.mark.timeout(120)
def test_a_units_process_killed_mid_job_resumes_and_the_job_completes(
    broker: BrokerThread,
    coordinator: ServiceThread,
    probe_factory: Callable[..., MqttProbe],
    root: str,
    tmp_path: Path,
) -> None:
    op = OperatorPeer(probe_factory(), Topics(root), "tester")
    state = tmp_path / "units.sqlite3"
    first = robots(broker.url, root, state)
    try:
        # A long carry: picked up at [1, 1], delivered at [8, 8].
        assert op.submit_job(Cell(1, 1), Cell(8, 8), 1.5, job_id="r1").accepted

        def carrying() -> str | None:
            jobs = op.listed_jobs()
            job = jobs.get("r1")
            return job.unit if job is not None and job.state == "to_dropoff" else None

        unit = wait_for(carrying, 30, what="r1 on its way to the dropoff")
        first.send_signal(signal.SIGKILL)  # no goodbye, nothing flushed by us
        first.wait(10)
        was = op.last_state(unit)
        assert was is not None and was.job_id == "r1"
        seen = len(op.states(unit))
        second = robots(broker.url, root, state)
        try:
            back = wait_for(lambda: op.states(unit)[seen:], 20, what=f"{unit} back")[0]
            # Where it stood (at most the one square it moved after its last state) and loaded.
            assert back.position.manhattan(was.position) <= 1, (back.position, was.position)
            assert (back.job_id, back.load_kg) == ("r1", 1.5)
            wait_for(lambda: op.all_final(["r1"]), 60, what="r1 final")
            assert op.listed_jobs()["r1"].state == "done", op.listed_jobs()["r1"]
        finally:
            second.send_signal(signal.SIGTERM)
            assert second.wait(20) == 0
    finally:
        if first.poll() is None:
            first.kill()


def test_a_fresh_state_file_starts_from_the_scenario_and_keeps_each_step(tmp_path: Path) -> None:
    scenario = load_scenario(PLAYFIELD)
    state = tmp_path / "units.sqlite3"
    fleet = Fleet(scenario, "mqtt://127.0.0.1:1", step=STEP_S, state_path=state)
    starts = {u.id: u.start for u in scenario.units}
    assert {uid: lg.position for uid, lg in fleet.logic.items()} == starts
    saved = SavedUnits(state).load(scenario.grid, list(starts))
    assert saved == {uid: Saved(cell) for uid, cell in starts.items()}


def write_row(state: Path, *row: object) -> None:
    SavedUnits(state).close()  # the table
    with sqlite3.connect(state) as db:
        db.execute(
            "INSERT OR REPLACE INTO units (id, x, y, job_id, load_kg, battery_pct)"
            " VALUES (?, ?, ?, ?, ?, ?)",
            row if len(row) == 6 else (*row, None),  # no battery unless the row gives one
        )


@pytest.mark.parametrize(
    ("row", "problem"),
    [
        (("unit1", 99, 0, None, 0.0), "not a free square"),
        (("unit1", 0, 0, None, -1.0), "is not a mass"),
        (("unit1", 0, 0, "bad id!", 1.0), "job id"),
        (("unit1", 0, 0, "j1", 500.0), "over its capacity"),
    ],
)
def test_a_bad_state_file_is_refused_naming_the_problem(
    tmp_path: Path, row: tuple[object, ...], problem: str
) -> None:
    state = tmp_path / "units.sqlite3"
    write_row(state, *row)
    with pytest.raises(ConfigError, match=problem):
        Fleet(load_scenario(PLAYFIELD), "mqtt://127.0.0.1:1", state_path=state)


def test_two_units_on_one_square_or_a_file_that_is_no_database_are_refused(tmp_path: Path) -> None:
    scenario = load_scenario(PLAYFIELD)
    state = tmp_path / "units.sqlite3"
    other = next(u for u in scenario.units if u.id != "unit1")
    write_row(state, "unit1", other.start.x, other.start.y, None, 0.0)
    with pytest.raises(ConfigError, match="would both stand on"):
        Fleet(scenario, "mqtt://127.0.0.1:1", state_path=state)
    junk = tmp_path / "junk.sqlite3"
    junk.write_bytes(b"this is not a database" * 100)
    with pytest.raises(ConfigError, match=r"junk\.sqlite3"):
        Fleet(scenario, "mqtt://127.0.0.1:1", state_path=junk)


def test_a_process_s_units_step_in_groups_of_at_most_twelve_spread_over_the_step_period(
    tmp_path: Path,
) -> None:
    # One process's units stepping in the same instant sent their states in one burst, and the
    # last of them waited for all the others (bench/README.md, issue 15).
    scenario = make_scenario(50, 0, tmp_path)
    fleet = Fleet(scenario, "mqtt://127.0.0.1:1", step=0.2)
    phases = [round(r.phase_s, 6) for r in fleet.shells.values()]
    assert sorted(set(phases)) == [0.0, 0.04, 0.08, 0.12, 0.16]
    assert all(phases.count(p) == 10 for p in set(phases))
    few = Fleet(scenario, "mqtt://127.0.0.1:1", step=0.2, units=[u.id for u in scenario.units[:12]])
    assert {r.phase_s for r in few.shells.values()} == {0.0}  # a dozen step together


def test_a_restarted_fleet_resumes_each_battery_where_it_was(tmp_path: Path) -> None:
    scenario = load_scenario(PLAYFIELD)
    powered = replace(
        scenario,
        units=tuple(replace(u, battery=BatterySpec(start_pct=90.0)) for u in scenario.units),
    )
    state = tmp_path / "units.sqlite3"
    first = Fleet(powered, "mqtt://127.0.0.1:1", step=STEP_S, state_path=state)
    saved = SavedUnits(state).load(powered.grid, ["unit1"])
    assert saved["unit1"].battery_pct == 90.0  # kept from the start
    first.saved.close()  # type: ignore[union-attr]
    write_row(state, "unit1", 0, 0, None, 0.0, 37.5)
    again = Fleet(powered, "mqtt://127.0.0.1:1", step=STEP_S, state_path=state)
    battery = again.logic["unit1"].battery
    assert battery is not None and battery.pct == 37.5 and battery.model.move_pct == 0.5
    unit2 = again.logic["unit2"].battery
    assert unit2 is not None and unit2.pct == 90.0
    # A scenario without batteries ignores a saved charge.
    plain = Fleet(scenario, "mqtt://127.0.0.1:1", step=STEP_S, state_path=state)
    assert plain.logic["unit1"].battery is None


def test_a_saved_charge_that_is_no_percent_is_refused(tmp_path: Path) -> None:
    state = tmp_path / "units.sqlite3"
    write_row(state, "unit1", 0, 0, None, 0.0, 120.0)
    with pytest.raises(ConfigError, match=r"battery 120\.0 is not a charge of 0 to 100 %"):
        Fleet(load_scenario(PLAYFIELD), "mqtt://127.0.0.1:1", state_path=state)


def test_a_state_file_from_before_batteries_is_read_and_kept(tmp_path: Path) -> None:
    state = tmp_path / "units.sqlite3"
    with sqlite3.connect(state) as db:
        db.execute(
            "CREATE TABLE units (id TEXT PRIMARY KEY, x INTEGER NOT NULL, y INTEGER NOT NULL,"
            " job_id TEXT, load_kg REAL NOT NULL)"
        )
        db.execute("INSERT INTO units VALUES ('unit1', 1, 0, NULL, 0.0)")
    saved = SavedUnits(state).load(load_scenario(PLAYFIELD).grid, ["unit1"])
    assert saved == {"unit1": Saved(Cell(1, 0))}
