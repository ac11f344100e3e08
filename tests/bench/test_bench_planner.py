"""The planner benchmark: its data loaders, its runs (checked by the validator) and its CLI."""

from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from gridfleet.bench import anchors as bench_anchors
from gridfleet.bench import runs as bench_runs
from gridfleet.bench import scale as scale_module
from gridfleet.bench.anchors import (
    ANCHORS_ENV,
    LifelongInstance,
    ScenAgent,
    find_anchors,
    load_instance,
    load_scen,
)
from gridfleet.bench.runs import random_instance, run_lifelong, run_one_shot
from gridfleet.bench.scale import run_scale
from gridfleet.coordinator.planning.planner import AgentSpec, Planner
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell, GridMap
from gridfleet.paths import DistanceFieldCache

from support.paths import REPO

pytestmark = pytest.mark.slow  # seconds a test: in make test, not in test-fast

CORRIDOR = GridMap.from_rows(["....."])
BAY = GridMap.from_rows([".....", "@@.@@"])  # a corridor with one passing bay
SHARED_ANCHORS = Path(__file__).resolve().parents[3] / "shared" / "anchors"


def ticker() -> object:
    """A fake clock that advances 1 ms per reading: timings become exact."""
    now = [0.0]

    def clock() -> float:
        now[0] += 0.001
        return now[0]

    return clock


def write_anchors(root: Path) -> Path:
    """A tiny anchors folder: one map, one lifelong instance, one Moving AI scenario."""
    (root / "maps").mkdir(parents=True)
    (root / "instances").mkdir()
    (root / "maps" / "tiny.map").write_text(
        "type octile\nheight 3\nwidth 6\nmap\n......\n.@@@@.\n......\n"
    )
    instance = {
        "name": "TINY",
        "map": "tiny.map",
        "team_size": 2,
        "horizon": 40,
        "starts": [[0, 0], [2, 5]],
        "tasks": [[[0, 5]], [[2, 0]], [[0, 0]], [[2, 5]]],
        "best_tasks_finished": 3,
        "action_model": "MAPF_T",
    }
    (root / "instances" / "TINY.json").write_text(json.dumps(instance))
    (root / "instances" / "STARTS-ONLY.json").write_text('{"map": "tiny.map", "starts": []}')
    (root / "maps" / "tiny.scen").write_text(
        "version 1\n0\ttiny.map\t6\t3\t0\t0\t5\t2\t7\n0\ttiny.map\t6\t3\t5\t2\t0\t0\t7\n"
    )
    return root


# ---- loaders ---------------------------------------------------------------------------------


def test_an_instance_loads_with_rows_and_columns_turned_into_squares(tmp_path: Path) -> None:
    inst = load_instance(write_anchors(tmp_path) / "instances" / "TINY.json")
    assert inst.starts == (Cell(0, 0), Cell(5, 2))  # [row, col] -> Cell(x=col, y=row)
    assert inst.tasks[0] == (Cell(5, 0),) and inst.agents == 2 and inst.horizon == 40
    assert inst.best_tasks_finished == 3 and inst.action_model == "MAPF_T"


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"starts": [[1, 1], [0, 0]]}, "[1, 1] is not a free square"),
        ({"starts": [[0, 0], [0, 0]]}, "two agents start on one square"),
        ({"starts": [[0, "a"]]}, "whole numbers"),
        ({"tasks": [[[0, 5]]]}, "a non-empty task for every agent"),
        ({"tasks": [[[0, 5]], []]}, "a non-empty task for every agent"),
        ({"horizon": 0}, "'horizon' must be a whole number"),
        ({"map": "nope.map"}, "no such map file"),
        ({"tasks": None}, "no 'tasks'"),
    ],
)
def test_a_bad_instance_is_one_error_naming_the_file(
    tmp_path: Path, change: dict[str, object], problem: str
) -> None:
    path = write_anchors(tmp_path) / "instances" / "TINY.json"
    data = {**json.loads(path.read_text()), **change}
    path.write_text(json.dumps({k: v for k, v in data.items() if v is not None}))
    with pytest.raises(ConfigError, match=re.escape(problem)) as info:
        load_instance(path)
    assert str(path) in str(info.value)


def test_an_unreadable_instance_is_one_error(tmp_path: Path) -> None:
    path = write_anchors(tmp_path) / "instances" / "TINY.json"
    path.write_text("{not json")
    with pytest.raises(ConfigError, match="not a readable JSON instance"):
        load_instance(path)


def test_a_moving_ai_scenario_loads_its_map_and_agents(tmp_path: Path) -> None:
    grid, agents = load_scen(write_anchors(tmp_path) / "maps" / "tiny.scen")
    assert (grid.width, grid.height) == (6, 3)
    assert agents == [ScenAgent(Cell(0, 0), Cell(5, 2)), ScenAgent(Cell(5, 2), Cell(0, 0))]


@pytest.mark.parametrize(
    ("body", "problem"),
    [
        ("0\ttiny.map\t6\t3\t0\t0\t5\t2\t7\n", "expected 'version 1'"),
        ("version 1\n0\ttiny.map\t6\t3\t0\t0\n", "expected 9 tab-separated fields"),
        ("version 1\n0\ttiny.map\t6\t3\t0\tx\t5\t2\t7\n", "whole numbers"),
        ("version 1\n0\ttiny.map\t6\t3\t1\t1\t5\t2\t7\n", "start [1, 1] is not free"),
        ("version 1\n0\tnope.map\t6\t3\t0\t0\t5\t2\t7\n", "no such map file"),
        ("version 1\n", "no agents"),
    ],
)
def test_a_bad_scenario_line_is_named(tmp_path: Path, body: str, problem: str) -> None:
    path = write_anchors(tmp_path) / "maps" / "tiny.scen"
    path.write_text(body)
    with pytest.raises(ConfigError, match=re.escape(problem)):
        load_scen(path)


def test_missing_benchmark_data_says_how_to_point_at_it(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="pass --anchors DIR"):
        find_anchors(tmp_path / "nothing")


def test_missing_data_beside_the_checkout_is_named_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    checkout = tmp_path / "gridfleet"
    (checkout / "bench").mkdir(parents=True)
    monkeypatch.setattr(bench_anchors, "__file__", str(checkout / "bench" / "anchors.py"))
    monkeypatch.delenv(ANCHORS_ENV, raising=False)
    monkeypatch.chdir(checkout)  # run from the checkout: both places are the same folder
    with pytest.raises(ConfigError) as caught:
        find_anchors(None)
    assert str(caught.value).count(str(tmp_path / "shared" / "anchors")) == 1


@pytest.mark.skipif(not SHARED_ANCHORS.is_dir(), reason="the public benchmark data is not here")
def test_every_shipped_benchmark_file_loads() -> None:
    for path in sorted((SHARED_ANCHORS / "instances").glob("*.json")):
        if json.loads(path.read_text()).get("tasks"):
            inst = load_instance(path)
            assert inst.agents == json.loads(path.read_text())["team_size"]
    grid, agents = load_scen(SHARED_ANCHORS / "maps" / "random-32-32-10-random-1.scen")
    assert len(agents) > 400 and grid.width == 32


# ---- runs ------------------------------------------------------------------------------------


def test_lifelong_counts_finished_tasks_and_notices_the_stream_running_out() -> None:
    # One agent runs the corridor end to end: 4 ticks a task, three tasks in all.
    tasks = ((Cell(4, 0),), (Cell(0, 0),), (Cell(4, 0),))
    inst = LifelongInstance("run", CORRIDOR, (Cell(0, 0),), tasks, horizon=20)
    result = run_lifelong(inst, clock=ticker())  # type: ignore[arg-type]
    assert (result.tasks_finished, result.exhausted_at, result.violations) == (3, 11, 0)
    assert result.ticks == 20 and result.timing.median_ms == pytest.approx(1.0)
    capped = run_lifelong(inst, horizon=8)
    assert (capped.tasks_finished, capped.exhausted_at) == (2, None)


def test_a_multi_errand_task_finishes_when_its_last_errand_is_reached() -> None:
    inst = LifelongInstance("errands", CORRIDOR, (Cell(0, 0),), ((Cell(4, 0), Cell(2, 0)),), 6)
    assert run_lifelong(inst).tasks_finished == 1  # 4 ticks out, 2 back


def test_a_pool_of_known_tasks_goes_to_the_nearest_agents_and_refills_as_tasks_finish() -> None:
    # MR24's rule: two tasks known at the start, one more for each finished. The stream's own
    # order would send the agent at 0 to the far end first; the allocator picks the near task.
    tasks = ((Cell(4, 0),), (Cell(1, 0),), (Cell(0, 0),))
    pooled = LifelongInstance("pool", CORRIDOR, (Cell(0, 0),), tasks, horizon=3, open_tasks=2)
    streamed = LifelongInstance("stream", CORRIDOR, (Cell(0, 0),), tasks, horizon=3)
    assert run_lifelong(streamed).tasks_finished == 0  # 4 squares to the first errand
    # Task 1 (1 tick), then task 2, revealed meanwhile, (1 tick back) before the far task 0.
    assert run_lifelong(pooled).tasks_finished == 2
    # As the competition's simulator, the pool goes through the task file again: never runs out.
    again = run_lifelong(replace(pooled, horizon=20))
    assert again.exhausted_at is None and again.tasks_finished > len(tasks)
    assert again.finished_by_tick[2] == 2 and again.finished_by_tick[-1] == again.tasks_finished


def test_the_pool_gives_a_fleet_its_tasks_a_batch_at_a_time_each_task_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Small batches and offers stand in for 10,000 agents and 15,000 open tasks.
    monkeypatch.setattr(bench_runs, "ALLOCATE_AT_MOST", 2)
    monkeypatch.setattr(bench_runs, "OFFER_AT_MOST", 3)
    monkeypatch.setattr(bench_runs, "OFFER_EACH", 1)
    grid = GridMap.from_rows(["." * 8] * 4)
    tasks = tuple((Cell(x, y), Cell(7 - x, 3 - y)) for y in range(2) for x in range(0, 8, 2))
    pool = bench_runs._Pool(tasks, 8, DistanceFieldCache(grid))
    names = [str(i) for i in range(5)]
    position = {a: Cell(int(a), 3) for a in names}
    errands: dict[str, list[Cell]] = {a: [] for a in names}
    errands["4"] = [Cell(0, 0)]  # busy: a task once given out stays with its agent
    pool.give(names[:4], position, errands)
    given = [tuple(errands[a]) for a in names[:4]]
    assert all(given) and len(set(given)) == 4 and errands["4"] == [Cell(0, 0)]
    assert all(position[a].manhattan(errands[a][0]) <= 3 for a in names[:4])  # the near ones
    inst = LifelongInstance("pool", grid, tuple(position.values()), tasks, 60, open_tasks=6)
    result = run_lifelong(inst)
    assert result.violations == 0 and result.tasks_finished > len(tasks)  # round the file again


def test_an_instance_file_runs_by_path_under_mr24_rules(tmp_path: Path) -> None:
    anchors = write_anchors(tmp_path)
    (tmp_path / "instances-10k").mkdir()
    path = tmp_path / "instances-10k" / "MR24-TINY.json"
    tasks = [[[0, 5], [2, 0]], [[2, 5], [0, 0]], [[0, 3], [2, 2]], [[2, 4], [0, 1]]]
    mr24 = {
        "map": "tiny.map", "team_size": 2, "horizon": 200, "starts": [[0, 0], [2, 5]],
        "tasks": tasks, "task_reveal_t": [0, 0, 0, 1], "best_tasks_finished": 10,
        "action_model": "MAPF_T",
    }  # fmt: skip
    path.write_text(json.dumps(mr24))
    out = bench("--instance", str(path), "--horizon", "50", "--json")
    assert out.returncode == 0, out.stderr
    (row,) = json.loads(out.stdout)["instance"]
    assert row["instance"] == "MR24-TINY" and (row["ticks"], row["of_ticks"]) == (50, 200)
    assert row["violations"] == 0 and row["tasks_finished"] >= 3 and row["best_in_competition"]
    assert row["ratio_to_best"] == row["tasks_finished"] / 10
    assert row["projected_linear"] == row["tasks_finished"] * 4  # stopped at a quarter
    assert row["first_tick_s"] > 0 and row["peak_rss_mb"] > 0 and row["tick_ms_p99"] > 0
    whole = bench("--instance", str(path), "--anchors", str(anchors), "--json")
    (row,) = json.loads(whole.stdout)["instance"]
    assert row["ticks"] == 200 and "finished_by_1000" not in row  # checkpoints within the run
    assert row["projected_linear"] is None and row["violations"] == 0
    assert "tasks_finished" in bench("--instance", str(path), "--horizon", "5").stdout


def test_an_instance_with_reveal_times_keeps_as_many_tasks_known_as_it_starts_with(
    tmp_path: Path,
) -> None:
    path = write_anchors(tmp_path) / "instances" / "TINY.json"
    data = json.loads(path.read_text())
    path.write_text(json.dumps({**data, "task_reveal_t": [0, 0, 0, 7]}))
    assert load_instance(path).open_tasks == 3
    path.write_text(json.dumps({**data, "task_reveal_t": "soon"}))
    with pytest.raises(ConfigError, match="'task_reveal_t' must be a list of ticks"):
        load_instance(path)


class Teleporter:
    """A broken planner: every agent jumps straight to its target."""

    def step(self, agents: dict[str, AgentSpec]) -> dict[str, Cell]:
        return {a: s.target or s.position for a, s in agents.items()}


def test_an_unsafe_planner_is_caught_by_the_validator() -> None:
    inst = LifelongInstance(
        "bad", CORRIDOR, (Cell(0, 0), Cell(4, 0)), ((Cell(4, 0),), (Cell(0, 0),)), 3
    )
    result = run_lifelong(inst, planner=Teleporter())
    assert result.violations > 0
    shot = run_one_shot(CORRIDOR, [ScenAgent(Cell(0, 0), Cell(3, 0))], 5, planner=Teleporter())
    assert shot.violations == 1  # a jump of three squares


def test_one_shot_swap_through_a_bay_is_solved_above_the_lower_bound() -> None:
    agents = [ScenAgent(Cell(0, 0), Cell(4, 0)), ScenAgent(Cell(4, 0), Cell(0, 0))]
    result = run_one_shot(BAY, agents, max_steps=50)
    assert result.solved and result.violations == 0 and result.at_goal == 2
    assert result.lower_bound == 8
    assert result.sum_of_costs is not None and result.sum_of_costs > result.lower_bound
    assert result.makespan is not None and result.makespan >= 4


def test_one_shot_out_of_steps_is_reported_unsolved() -> None:
    result = run_one_shot(CORRIDOR, [ScenAgent(Cell(0, 0), Cell(4, 0))], max_steps=2)
    assert not result.solved and result.makespan is None and result.at_goal == 0


def test_random_instances_stay_in_the_largest_region() -> None:
    grid = GridMap.from_rows(["..@.....", "..@.....", "..@....."])  # 6 squares left, 15 right
    inst = random_instance(grid, 10, horizon=20, seed=3)
    assert len(set(inst.starts)) == 10 and all(c.x >= 3 for c in inst.starts)
    assert all(t[0].x >= 3 for t in inst.tasks)
    assert random_instance(grid, 10, horizon=20, seed=3) == inst  # seeded: the same again
    with pytest.raises(ValueError, match="do not fit"):
        random_instance(grid, 16, horizon=5)


# ---- the command ---------------------------------------------------------------------------


def bench(*args: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "gridfleet", "bench", "planner", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)


def test_the_command_reports_every_suite_as_json(tmp_path: Path) -> None:
    anchors = write_anchors(tmp_path)
    out = bench(
        "--anchors", str(anchors), "--scen", "tiny.scen", "--agents", "1,2",
        "--scale-map", "tiny.map", "--scale-agents", "3", "--scale-ticks", "10",
        "--scale-pick-faces", "2", "--scale-stations", "1", "--json",
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    (life,) = report["lifelong"]  # the starts-only file is not a lifelong instance
    assert life["instance"] == "TINY" and life["best_in_competition"] == 3
    assert life["tasks_finished"] >= 2 and life["violations"] == 0 and life["ms_p50"] > 0
    assert [r["agents"] for r in report["oneshot"]] == [1, 2]
    assert all(r["solved"] and r["sum_of_costs"] >= r["lower_bound"] for r in report["oneshot"])
    assert all(0 < r["planning_s"] < 5 for r in report["oneshot"])
    (scale,) = report["scale"]
    assert scale["agents"] == 3 and scale["ticks"] == 10 and scale["violations"] == 0
    assert scale["tasks_finished"] >= 1 and scale["peak_rss_mb"] > 0 and scale["first_tick_s"] > 0


def test_the_command_prints_tables_by_default(tmp_path: Path) -> None:
    out = bench("--anchors", str(write_anchors(tmp_path)), "--suite", "lifelong")
    assert out.returncode == 0, out.stderr
    assert "TINY" in out.stdout and "tasks_finished" in out.stdout and "MAPF_T" in out.stdout


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        (["--suite", "fastest"], "--suite: unknown ['fastest']"),
        (["--instances", "NOPE"], "--instances: no ['NOPE']"),
        (["--agents", "5", "--suite", "oneshot", "--scen", "tiny.scen"], "has 2 agents, not 5"),
        (["--agents", "0"], "expected counts of at least 1"),
        (["--repeat", "two"], "expected whole numbers"),
        (["--suite", "scale", "--scale-map", "tiny.map", "--scale-agents", "99"], "do not fit"),
        (["--guidance", "magic"], "invalid choice: 'magic'"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(
    tmp_path: Path, args: list[str], problem: str
) -> None:
    out = bench("--anchors", str(write_anchors(tmp_path)), *args)
    assert out.returncode == 2 and problem in out.stderr, out.stderr
    assert "Traceback" not in out.stderr


def test_no_benchmark_data_is_one_line_and_exit_2(tmp_path: Path) -> None:
    out = bench("--anchors", str(tmp_path))
    assert (
        out.returncode == 2 and "no benchmark data" in out.stderr and "Traceback" not in out.stderr
    )


def test_a_reader_that_went_away_ends_the_command_quietly(tmp_path: Path) -> None:
    # As `gridfleet bench planner | head -1`: the pipe's reading end is gone before the tables.
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        cmd = [sys.executable, "-m", "gridfleet", "bench", "planner", "--suite", "lifelong"]
        out = subprocess.run(
            [*cmd, "--anchors", str(write_anchors(tmp_path))],
            stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=120, check=False,
        )  # fmt: skip
    finally:
        os.close(write_end)
    assert out.returncode == 141 and "Traceback" not in out.stderr, out.stderr


def test_a_scale_run_allocates_jobs_and_finishes_them_the_same_way_twice() -> None:
    grid = GridMap.from_rows(["." * 16] * 12)
    first = run_scale(grid, 20, 150, seed=4, pick_faces=10, stations=3)
    assert first.tasks_finished >= 10 and first.violations == 0
    assert 0 < first.tasks_second_half < first.tasks_finished
    assert first.steady_tasks_per_tick == first.tasks_second_half / 75
    assert 1 <= first.travel_per_job <= 16 + 12  # a job crosses the room at most twice
    assert len(first.planner.seconds) == len(first.allocation.seconds) == 149
    assert run_scale(grid, 20, 150, seed=4, pick_faces=10, stations=3).tasks_finished == (
        first.tasks_finished
    )
    with pytest.raises(ValueError, match="do not fit"):
        run_scale(grid, 190, 5, pick_faces=10, stations=3)


@pytest.mark.parametrize(
    ("guidance", "guided", "lanes"),
    [("auto", True, False), ("off", False, False), ("lanes", False, True), ("paths", True, False)],
)
def test_a_scale_run_is_planned_with_the_guidance_asked_for(
    monkeypatch: pytest.MonkeyPatch, guidance: str, guided: bool, lanes: bool
) -> None:
    made: list[Planner] = []
    real = scale_module.Planner

    def recorded(*args: Any, **kwargs: Any) -> Planner:
        made.append(real(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(scale_module, "Planner", recorded)
    grid = GridMap.from_rows(["." * 16] * 12)  # small: guide paths, no lanes, unless asked
    result = run_scale(grid, 20, 60, seed=4, pick_faces=10, stations=3, guidance=guidance)
    assert result.violations == 0 and result.tasks_finished > 0
    (planner,) = made
    assert (planner.guidance is not None, planner.lanes is not None) == (guided, lanes)


def test_the_command_draws_its_figures_into_the_file_named(tmp_path: Path) -> None:
    picture = tmp_path / "planner.png"
    out = bench(
        "--anchors", str(write_anchors(tmp_path)), "--suite", "lifelong,scale",
        "--scale-map", "tiny.map", "--scale-agents", "3", "--scale-ticks", "5",
        "--scale-pick-faces", "2", "--scale-stations", "1", "--plot", str(picture),
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    ("plot", "says"),
    [
        ("no-such-folder/planner.png", "there is no folder {tmp}/no-such-folder"),
        ("planner.txt", "give a file ending in one of "),  # then each kind matplotlib writes
    ],
    ids=["no-folder", "unknown-kind"],
)
def test_a_plot_that_cannot_be_written_is_one_line_and_exit_2_before_any_run(
    plot: str, says: str, tmp_path: Path
) -> None:
    # No benchmark data where --anchors says: a suite that ran first would say that instead.
    out = bench("--anchors", str(tmp_path), "--suite", "lifelong", "--plot", str(tmp_path / plot))
    assert out.returncode == 2, out.stderr
    [line] = out.stderr.strip().splitlines()
    said = f"gridfleet bench: error: --plot: cannot write {tmp_path / plot}: "
    assert line.startswith(said + says.format(tmp=tmp_path)), line
    if plot.endswith(".txt"):
        assert {".png", ".svg", ".pdf"} <= set(line.removeprefix(said + says).split(", ")), line
    assert not (tmp_path / plot).exists()


def test_the_pinned_checksums_name_every_file_the_default_suites_read() -> None:
    pinned = (REPO / "bench" / "anchors.sha256").read_text()
    rows = [line.split() for line in pinned.splitlines()]
    assert all(len(r) == 2 and len(r[0]) == 64 for r in rows)
    named = {r[1] for r in rows}
    assert {"maps/warehouse_large.map", "maps/random-32-32-10-random-1.scen"} <= named
    assert {f"instances/MR23-I-0{i}.json" for i in (3, 4, 5, 7, 8)} <= named


@pytest.mark.skipif(not SHARED_ANCHORS.is_dir(), reason="the public benchmark data is not here")
def test_the_benchmark_data_here_is_what_the_checksums_pin() -> None:
    pinned = (REPO / "bench" / "anchors.sha256").read_text()
    for digest, name in (line.split() for line in pinned.splitlines()):
        assert hashlib.sha256((SHARED_ANCHORS / name).read_bytes()).hexdigest() == digest, name
