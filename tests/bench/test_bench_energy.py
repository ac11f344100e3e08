"""`gridfleet bench energy`: three arms on one scenario, every figure taken from its run."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from gridfleet.bench import energy as bench_energy
from gridfleet.scenario import load_scenario

from support.paths import MAPS, REPO

BUDGET = 400  # steps: the playfield's endless run finishes in about 190
FLAGS = ("--scenario", "playfield-energy", "--seeds", "1", "--max-steps", str(BUDGET))


def bench(*flags: str) -> tuple[int, str]:
    """Run the bench in this process with `flags`: its exit code and its stdout."""
    parser = argparse.ArgumentParser()
    bench_energy.add_arguments(parser)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = bench_energy.run(parser.parse_args(list(flags)))
    return code, out.getvalue()


def run_of(figures: dict[str, Any], arm: str) -> dict[str, Any]:
    (found,) = [r for r in figures["runs"] if r["arm"] == arm]
    return found


@pytest.fixture(scope="module")
def figures() -> dict[str, Any]:
    """One seed of the energy playfield, every arm, as the bench's JSON (the runs are
    deterministic: the command below makes the same ones)."""
    code, out = bench(*FLAGS, "--json")
    assert code == 0, out
    parsed: dict[str, Any] = json.loads(out)
    return parsed


@pytest.mark.slow  # the bench's own runs: make test, not test-fast
def test_one_seed_on_the_energy_playfield_reports_each_arm_from_its_run(
    figures: dict[str, Any],
) -> None:
    assert (figures["scenario"], figures["units"], figures["chargers"], figures["jobs"]) == (
        "playfield-energy",
        4,
        2,
        60,
    )
    assert figures["seeds"] == [0] and figures["max_steps"] == BUDGET
    assert [(r["arm"], r["seed"]) for r in figures["runs"]] == [
        ("gridfleet", 0),
        ("naive", 0),
        ("endless", 0),
    ]
    for r in figures["runs"]:
        assert r["steps"] == (r["last_done_step"] if r["finished"] else BUDGET)
        assert r["jobs_done"] + r["jobs_failed"] + r["jobs_left"] == r["jobs"] == 60
        assert r["jobs_per_1000_steps"] == round(1000 * r["jobs_done"] / r["steps"], 2)
        assert r["collisions"] == 0 and r["wall_s"] > 0
    ours, naive, endless = (run_of(figures, arm) for arm in ("gridfleet", "naive", "endless"))
    # Endless batteries: no unit reports energy, so nothing charges, queues or runs low.
    assert endless["units_with_battery"] == 0 and endless["lowest_pct"] is None
    assert (endless["charging_unit_steps"], endless["charges"], endless["queued_unit_steps"]) == (
        0,
        0,
        0,
    )
    assert endless["finished"] and endless["jobs_done"] == 60
    # Ours: jobs done on charges, no unit ever empty (else the bench exits 1).
    assert ours["jobs_done"] > 0 and ours["units_with_battery"] == 4
    assert ours["charging_unit_steps"] > 0 and ours["charges"] > 0
    assert ours["units_empty"] == 0 and 0 < ours["lowest_pct"] < 100
    # Naive: its lowest charge is reported, and a unit at 0 % counts as empty.
    assert naive["units_with_battery"] == 4 and isinstance(naive["lowest_pct"], float)
    assert (naive["lowest_pct"] == 0.0) == (naive["units_empty"] > 0)
    # One seed: the medians are that run's figures, and the ratios are theirs.
    for arm in ("gridfleet", "naive", "endless"):
        row, one = figures["medians"][arm], run_of(figures, arm)
        assert (row["runs"], row["finished"]) == (1, int(one["finished"]))
        assert row["jobs_per_1000_steps"] == one["jobs_per_1000_steps"]
        assert row["charging_unit_steps"] == one["charging_unit_steps"]
        assert row["lowest_pct_of_all"] == one["lowest_pct"]
    # In the steps our run took: ours did all it did; the others what they had done by then.
    (at_ours,) = figures["at_ours_steps"]
    assert (at_ours["seed"], at_ours["steps"]) == (0, ours["steps"])
    assert at_ours["gridfleet"] == ours["jobs_done"]
    for other in (naive, endless):
        by_then = at_ours[other["arm"]]
        assert by_then <= other["jobs_done"]
        assert (by_then == other["jobs_done"]) == (other["last_done_step"] <= ours["steps"])
    assert figures["ours_over_naive_at_ours_steps"] == round(
        ours["jobs_done"] / at_ours["naive"], 3
    )
    assert figures["ours_over_naive"] == round(
        ours["jobs_per_1000_steps"] / naive["jobs_per_1000_steps"], 3
    )
    assert figures["ours_over_endless"] == round(
        ours["jobs_per_1000_steps"] / endless["jobs_per_1000_steps"], 3
    )


def test_endless_takes_out_every_battery_and_nothing_else() -> None:
    scenario = load_scenario(MAPS / "playfield-energy.toml")
    taken = bench_energy.endless(scenario)
    assert all(u.battery is not None for u in scenario.units)
    assert [u.battery for u in taken.units] == [None] * len(scenario.units)
    assert [(u.id, u.start, u.capacity) for u in taken.units] == [
        (u.id, u.start, u.capacity) for u in scenario.units
    ]
    assert (taken.jobs, taken.chargers, taken.grid) == (
        scenario.jobs,
        scenario.chargers,
        scenario.grid,
    )


@pytest.mark.slow  # the bench's own runs: make test, not test-fast
def test_a_unit_of_ours_that_starts_empty_makes_the_bench_exit_1(tmp_path: Path) -> None:
    scenario = tmp_path / "empty.toml"
    scenario.write_text(
        f'name = "empty"\nmap = "{MAPS / "playfield.map"}"\n'
        "[battery]\nstart_pct = 0.0\n"
        '[[units]]\nid = "u1"\nstart = [0, 0]\ncapacity = 5.0\n'
        "[[chargers]]\nsquare = [9, 5]\n"
        "[[jobs]]\npickup = [4, 4]\ndropoff = [0, 7]\nmass = 1.0\n",
        encoding="utf-8",
    )
    flags = ("--scenario", str(scenario), "--seeds", "1", "--max-steps", "30", "--json")
    code, out = bench(*flags)
    assert code == 1
    ours = run_of(json.loads(out), "gridfleet")
    assert (ours["units_empty"], ours["lowest_pct"], ours["jobs_done"]) == (1, 0.0, 0)
    assert not ours["finished"] and ours["steps"] == 30


@pytest.mark.slow  # the bench's own runs: make test, not test-fast
def test_the_command_prints_the_runs_figures_and_ratios(figures: dict[str, Any]) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "gridfleet", "bench", "energy", *FLAGS],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    out = done.stdout
    assert "medians per arm" in out and "jobs done in the steps our run took" in out
    endless = round(100 * figures["ours_over_endless"])
    assert f"ours reaches {endless} % of endless batteries' jobs per 1,000 steps" in out
    at_ours = figures["ours_over_naive_at_ours_steps"]
    verb = "beats naive by" if at_ours >= 1 else "is"
    assert f"ours {verb} {round(100 * abs(at_ours - 1))} % " in out
    unfinished = [f"{r['arm']} 1 of 1" for r in figures["runs"] if not r["finished"]]
    line = "not finished within the budget (their steps are the budget): " + ", ".join(unfinished)
    assert (line in out) == bool(unfinished), out
    for r in figures["runs"]:  # a progress line a run, on stderr
        assert (
            f"bench energy: seed 0 {r['arm']}: {r['jobs_done']}/60 jobs in {r['steps']} steps"
            in (done.stderr)
        )


@pytest.mark.parametrize(
    ("flags", "words"),
    [
        (["--scenario", "playfield"], "no unit has a battery (add [battery])"),
        (["--scenario", "playfield-energy", "--seeds", "0"], "--seeds and --max-steps"),
    ],
)
def test_a_scenario_or_flag_it_cannot_run_is_refused_in_one_line(
    flags: list[str], words: str
) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "gridfleet", "bench", "energy", *flags],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
    assert done.returncode == 2, done.stderr
    assert words in done.stderr.strip().splitlines()[-1]
