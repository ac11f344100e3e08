"""`gridfleet simulate` runs every shipped scenario to the end, safely, as a user runs it."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest

from gridfleet.bench.busy_scenario import make_busy
from gridfleet.scenario import load_scenario

from support.cli import gridfleet
from support.paths import MAPS

pytestmark = pytest.mark.slow  # seconds a test: in make test, not in test-fast

SCENARIOS = sorted(MAPS.glob("*.toml"))


def simulate(*args: str, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return gridfleet("simulate", *args, timeout=timeout)


def failure_report(out: subprocess.CompletedProcess[str]) -> str:
    """What a failed run left: where every unit stood and the jobs not done, else the raw tail."""
    try:
        result = json.loads(out.stdout)
        kept = {k: result[k] for k in ("finished", "steps", "collisions", "units")}
        kept["jobs_not_done"] = [j for j in result["jobs"] if j["state"] != "done"]
    except (ValueError, KeyError, TypeError):
        return out.stdout[-2000:] + out.stderr[-2000:]
    return json.dumps(kept) + out.stderr[-2000:]


@pytest.mark.timeout(300)
@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_every_shipped_scenario_finishes_safely(path: Path) -> None:
    out = simulate(str(path), "--step", "0.05", "--max-steps", "3000", "--json")
    assert out.returncode == 0, failure_report(out)
    result: dict[str, Any] = json.loads(out.stdout)
    assert result["finished"] is True
    assert result["collisions"] == 0
    scenario = load_scenario(path)
    capacity = {u.id: u.capacity for u in scenario.units}
    assert [u["id"] for u in result["units"]] == list(capacity)
    for unit in result["units"]:
        assert set(unit) >= {"id", "capacity", "position", "moves"}
        assert unit["capacity"] == capacity[unit["id"]]
    assert len(result["jobs"]) == len(scenario.jobs)
    for job in result["jobs"]:
        assert set(job) >= {"id", "pickup", "dropoff", "mass", "state", "unit", "done_step"}
        if job["mass"] <= max(capacity.values()):
            assert job["state"] == "done", job
            assert capacity[job["unit"]] >= job["mass"], job
            assert isinstance(job["done_step"], int)
        else:
            assert job["state"] == "rejected" and "capacity" in job["reason"], job
    assert [(g["unit"], g["target"]) for g in result["goals"]] == [
        (g.unit, list(g.target)) for g in scenario.goals
    ]
    for goal in result["goals"]:
        assert goal["reached"] is True and isinstance(goal["step"], int)
        # A reached goal releases the unit, which may then take a job that is still queued.
        later = [j for j in result["jobs"] if j["unit"] == goal["unit"] and j["state"] == "done"]
        if not any(j["done_step"] > goal["step"] for j in later):
            assert (
                next(u["position"] for u in result["units"] if u["id"] == goal["unit"])
                == (goal["target"])
            )
    assert result["messages"] > 0 and result["steps"] > 0
    # On batteries (the *-energy scenarios): no unit ever ran empty, and each charged.
    for unit, spec in zip(result["units"], scenario.units, strict=True):
        if spec.battery is not None:
            assert unit["reached_empty"] is False and unit["lowest_battery_pct"] > 0, unit
            assert unit["charges"] >= 1, unit
    assert result["units_empty"] == 0


def test_a_run_that_cannot_finish_in_time_says_so_and_exits_1() -> None:
    out = simulate(str(MAPS / "playfield.toml"), "--max-steps", "3", "--json")
    assert out.returncode == 1
    result = json.loads(out.stdout)
    assert result["finished"] is False and result["steps"] >= 3


def test_human_summary() -> None:
    out = simulate(str(MAPS / "corridor.toml"), "--step", "0.05")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("corridor: finished in ")
    assert "0 collisions" in out.stdout and "goal west -> [8, 1]: reached at step" in out.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["absent.toml"], "absent.toml: no such scenario file"),
        ([str(MAPS / "corridor.map")], "corridor.map"),
        ([str(MAPS / "corridor.toml"), "--step", "0"], "step"),
        ([str(MAPS / "corridor.toml"), "--max-steps", "0"], "max-steps"),
        ([str(MAPS / "corridor.toml"), "--window", "0"], "--window 0: give 1 to 32 squares"),
        (
            [str(MAPS / "corridor.toml"), "--energy-policy", "eager"],
            "--energy-policy eager: give gridfleet or naive",
        ),
    ],
)
def test_bad_input_is_one_clear_line(args: list[str], message: str) -> None:
    out = simulate(*args)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gridfleet simulate: error:"), out.stderr
    assert message in lines[0]


def test_a_job_refused_at_submission_is_listed_once_with_its_reason(tmp_path: Path) -> None:
    (tmp_path / "corridor.map").write_text((MAPS / "corridor.map").read_text())
    (tmp_path / "heavy.toml").write_text(
        'map = "corridor.map"\n'
        '[[units]]\nid = "west"\nstart = [0, 1]\ncapacity = 5.0\n'
        '[[jobs]]\npickup = [1, 1]\ndropoff = [2, 1]\nmass = 1.0\nid = "crate"\n'
        '[[jobs]]\npickup = [1, 1]\ndropoff = [3, 1]\nmass = 9.0\nid = "piano"\n'
    )
    out = simulate(str(tmp_path / "heavy.toml"), "--step", "0.05", "--json")
    assert out.returncode == 0, out.stderr
    jobs = json.loads(out.stdout)["jobs"]
    assert [(j["id"], j["state"], j["dropoff"]) for j in jobs] == [
        ("crate", "done", [2, 1]),
        ("piano", "rejected", [3, 1]),
    ]
    assert "5" in jobs[1]["reason"] and "9" in jobs[1]["reason"]  # mass against capacity


def test_a_scenario_without_units_is_refused_before_anything_starts(tmp_path: Path) -> None:
    (tmp_path / "m.map").write_text("type octile\nheight 1\nwidth 3\nmap\n...\n")
    (tmp_path / "empty.toml").write_text('map = "m.map"\n')
    out = simulate(str(tmp_path / "empty.toml"))
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.strip() == (
        f"gridfleet simulate: error: {tmp_path / 'empty.toml'}: no units to run (add [[units]] tables)"
    )


@pytest.mark.timeout(300)
def test_a_busy_fleet_at_a_5_ms_step_finishes_every_job(tmp_path: Path) -> None:
    # Issue 13's overload: 16 units and 40 jobs at 5 ms once ended with "no reply from the
    # coordinator to submit_job" (amqtt's queue, in the simulation's own interpreter, grew
    # without bound). Slower than nominal is fine; every job done is the point.
    scenario = make_busy(16, 40, 1, tmp_path)
    out = simulate(str(scenario.path), "--step", "0.005", "--max-steps", "20000", "--json")
    assert out.returncode == 0, failure_report(out)
    result: dict[str, Any] = json.loads(out.stdout)
    assert result["collisions"] == 0
    assert [j["state"] for j in result["jobs"]] == ["done"] * 40


def _without_wall_time(out: subprocess.CompletedProcess[str]) -> dict[str, Any]:
    assert out.returncode == 0, failure_report(out)
    result: dict[str, Any] = json.loads(out.stdout)
    del result["wall_time_s"]  # the one figure that is the machine's, not the run's
    return result


def test_a_deterministic_run_is_the_same_every_time() -> None:
    # Issue 14: warehouse took 184-417 steps over repeated runs; nobody could compare two
    # scenarios or two planner versions with it.
    args = (str(MAPS / "warehouse.toml"), "--deterministic", "--json")
    first, second = (_without_wall_time(simulate(*args, timeout=120)) for _ in range(2))
    assert first == second
    assert first["finished"] and first["collisions"] == 0
    assert all(isinstance(j["done_step"], int) for j in first["jobs"])


def test_a_deterministic_run_takes_no_broker() -> None:
    out = simulate(str(MAPS / "maze.toml"), "--deterministic", "--broker", "mqtt://127.0.0.1:1")
    assert out.returncode == 2
    assert "--deterministic runs without a broker" in out.stderr and "Traceback" not in out.stderr


def test_an_idle_unit_in_a_pocket_makes_way_for_a_job_ending_there(tmp_path: Path) -> None:
    # Issue 14's hour of `up --demo`: an idle unit at the end of a dead end stood on another
    # unit's dropoff and the job waited 21 minutes. The idle unit now leaves to park elsewhere.
    (tmp_path / "pocket.map").write_text(
        "type octile\nheight 3\nwidth 5\nmap\n.@@@@\n.....\n.....\n"
    )
    (tmp_path / "pocket.toml").write_text(
        'map = "pocket.map"\n'
        '[[units]]\nid = "idle"\nstart = [0, 0]\ncapacity = 1.0\n'
        '[[units]]\nid = "runner"\nstart = [4, 2]\ncapacity = 5.0\n'
        '[[jobs]]\nid = "into-the-pocket"\npickup = [4, 1]\ndropoff = [0, 0]\nmass = 3.0\n'
    )
    out = simulate(str(tmp_path / "pocket.toml"), "--deterministic", "--max-steps", "200", "--json")
    result = _without_wall_time(out)
    assert result["collisions"] == 0
    assert [(j["state"], j["unit"]) for j in result["jobs"]] == [("done", "runner")]
    assert {u["id"]: u["position"] for u in result["units"]}["runner"] == [0, 0]


ENERGY_MAP = "type octile\nheight 3\nwidth 6\nmap\n......\n......\n......\n"
ENERGY_SCENARIO = (
    'map = "energy.map"\n'
    '[[units]]\nid = "runner"\nstart = [0, 0]\ncapacity = 5.0\n'
    "battery = { start_pct = 90.0, move_pct = 1.0, idle_pct_per_s = 0.1 }\n"
    '[[units]]\nid = "flat"\nstart = [5, 2]\ncapacity = 5.0\nbattery = { start_pct = 0.0 }\n'
    '[[units]]\nid = "mains"\nstart = [5, 0]\ncapacity = 1.0\n'  # no battery table: none
    "[[chargers]]\nsquare = [0, 2]\n"
    '[[jobs]]\nid = "near"\npickup = [1, 0]\ndropoff = [3, 1]\nmass = 2.0\n'
)


def _energy_scenario(tmp_path: Path) -> Path:
    (tmp_path / "energy.map").write_text(ENERGY_MAP)
    path = tmp_path / "energy.toml"
    path.write_text(ENERGY_SCENARIO)
    return path


def _check_energy_figures(result: dict[str, Any]) -> None:
    """What each unit's battery went through, as its moves and the run's steps say it must."""
    units = {u["id"]: u for u in result["units"]}
    assert [(j["id"], j["state"], j["unit"]) for j in result["jobs"]] == [
        ("near", "done", "runner")
    ]
    runner, flat, mains = units["runner"], units["flat"], units["mains"]
    assert runner["moves"] >= 4 and runner["charges"] == 0 and runner["charging_steps"] == 0
    # A move costs 1 %, a step standing 0.1 %: a simulated step is a second of a battery's life
    # at any step period. Counted in the unit's own steps: over MQTT they are more than the
    # coordinator's, by as many as the run's shutdown takes (16 more on a slow machine).
    assert runner["lowest_battery_pct"] == runner["battery_pct"]  # it only ever drained
    assert runner["standing_steps"] >= 1
    assert 90.0 - runner["moves"] - 0.1 * runner["standing_steps"] - 1.0 <= runner["battery_pct"]
    assert runner["battery_pct"] <= 90.0 - runner["moves"]
    assert runner["reached_empty"] is False
    # At 0 % from the start: it never moved, and it is counted as having been empty.
    assert (flat["moves"], flat["battery_pct"], flat["lowest_battery_pct"]) == (0, 0.0, 0.0)
    assert flat["reached_empty"] is True and flat["position"] == [5, 2]
    # A unit without a battery: nulls.
    assert (mains["battery_pct"], mains["lowest_battery_pct"], mains["charges"]) == (None, None, 0)
    assert mains["reached_empty"] is False
    assert result["units_empty"] == 1 and result["collisions"] == 0


def test_a_deterministic_run_reports_each_units_battery_charges_and_moves(tmp_path: Path) -> None:
    path = _energy_scenario(tmp_path)
    out = simulate(str(path), "--deterministic", "--step", "0.1", "--max-steps", "300", "--json")
    result = _without_wall_time(out)
    _check_energy_figures(result)
    runner = next(u for u in result["units"] if u["id"] == "runner")
    # In lockstep every unit steps once a coordinator step: the exact figure.
    standing = result["steps"] - runner["moves"]
    assert runner["battery_pct"] == round(90.0 - runner["moves"] - 0.1 * standing, 1)
    again = _without_wall_time(
        simulate(str(path), "--deterministic", "--step", "0.1", "--max-steps", "300", "--json")
    )
    assert again == result
    human = simulate(str(path), "--deterministic", "--step", "0.1", "--max-steps", "300")
    assert "batteries: lowest 0.0 % (flat), 0 charges, 1 ran empty" in human.stdout


def test_a_run_over_mqtt_reports_the_same_battery_figures(tmp_path: Path) -> None:
    path = _energy_scenario(tmp_path)
    out = simulate(str(path), "--step", "0.05", "--max-steps", "600", "--json")
    assert out.returncode == 0, failure_report(out)
    _check_energy_figures(json.loads(out.stdout))


def test_the_naive_energy_policy_is_chosen_and_runs_units_empty() -> None:
    # The same deterministic run under the coordinator's two policies: the naive baseline sends a
    # unit to charge only at critical and never checks that a job can be finished.
    runs = {
        policy: json.loads(
            simulate(
                str(MAPS / "playfield-energy.toml"),
                "--deterministic",
                "--energy-policy",
                policy,
                "--json",
                timeout=120,
            ).stdout
        )
        for policy in ("gridfleet", "naive")
    }
    ours, naive = runs["gridfleet"], runs["naive"]
    assert ours["finished"] and ours["units_empty"] == 0
    assert naive["units_empty"] >= 1
    lowest = {p: min(u["lowest_battery_pct"] for u in r["units"]) for p, r in runs.items()}
    assert lowest["naive"] == 0.0 < lowest["gridfleet"], lowest


# One unit at 60 %, a move 4 %: the job (12 moves with the way on to the charger) needs 80 %.
# Above good (50 %), the unit goes to charge for it (up to 81 %) all the same, as the job waits
# for it alone; charging takes hours at 0.01 % a second, so the job still waits at the end.
WAIT_SCENARIO = (
    'map = "energy.map"\n'
    '[[units]]\nid = "low"\nstart = [0, 0]\ncapacity = 5.0\n'
    "battery = { start_pct = 60.0, move_pct = 4.0, idle_pct_per_s = 0.0, "
    "charge_pct_per_s = 0.01 }\n"
    "[[chargers]]\nsquare = [0, 2]\n"
    '[[jobs]]\nid = "far"\npickup = [5, 0]\ndropoff = [5, 2]\nmass = 2.0\n'
)
FAR_WAITS = re.compile(
    r"every unit that can carry 2\.0 kg is charging \(low charging: \d+ % of 81 %\)"
)


@pytest.mark.parametrize(
    "mode",
    [
        pytest.param(["--deterministic"], id="deterministic"),
        pytest.param([], id="mqtt", marks=pytest.mark.slow),
    ],
)
def test_a_job_not_done_says_why_it_waits(tmp_path: Path, mode: list[str]) -> None:
    (tmp_path / "energy.map").write_text(ENERGY_MAP)
    path = tmp_path / "wait.toml"
    path.write_text(WAIT_SCENARIO)
    args = (str(path), *mode, "--step", "0.05", "--max-steps", "40")
    out = simulate(*args, "--json")
    assert out.returncode == 1, failure_report(out)
    (job,) = json.loads(out.stdout)["jobs"]
    assert (job["state"], job["wait"]) == ("queued", "unit_charging")
    assert FAR_WAITS.fullmatch(job["wait_reason"]), job
    human = simulate(*args)
    listed = [line for line in human.stdout.splitlines() if line.startswith("  far: ")]
    assert len(listed) == 1 and listed[0].endswith(" [unit_charging]"), listed
    assert FAR_WAITS.fullmatch(
        listed[0][len("  far: queued, waiting: ") : -len(" [unit_charging]")]
    )
    # Under the naive policy (chosen for the coordinator in lockstep or in its thread) the same
    # unit takes the job at once, and a job done waits for nothing.
    naive = simulate(*args, "--energy-policy", "naive", "--json")
    assert naive.returncode == 0, failure_report(naive)
    (done,) = json.loads(naive.stdout)["jobs"]
    assert (done["state"], done["unit"], done["wait"], done["wait_reason"]) == (
        "done",
        "low",
        None,
        None,
    )
