"""A fleet's units sharded over processes (`gridfleet robots --workers N`): one world for all of
them (sensors and moves see every unit, refusals are counted across processes), every job done,
and the stop reaching every shard."""

from __future__ import annotations

import json
import multiprocessing
import pickle
import signal
import subprocess
import sys
from collections.abc import Callable
from multiprocessing.queues import Queue
from multiprocessing.synchronize import Event
from pathlib import Path

import psutil
import pytest

from gridfleet.errors import ConfigError
from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.maps import format_map
from gridfleet.protocol import Topics
from gridfleet.robots.shards import shares, workers_for
from gridfleet.robots.shared_world import SharedHandle, SharedWorld
from gridfleet.scenario import Scenario, load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import coordinator_thread

from support.operator_peer import OperatorPeer
from support.paths import MAPS
from support.probe import MqttProbe
from support.wait import wait_for

PLAYFIELD = MAPS / "playfield.toml"
STEP_S = 0.05


def test_units_are_dealt_evenly_and_up_picks_a_process_per_50_units() -> None:
    assert shares(["a", "b", "c", "d", "e"], 2) == [["a", "c", "e"], ["b", "d"]]
    assert shares(["a", "b"], 4) == [["a"], ["b"]]  # never an empty worker
    with pytest.raises(ConfigError, match="--workers 0"):
        shares(["a"], 0)
    assert [workers_for(n, cpus=2) for n in (4, 50, 51, 100, 500)] == [1, 1, 2, 2, 2]
    assert workers_for(500, cpus=8) == 8


def _line(tmp_path: Path) -> Scenario:
    """A corridor of three squares: unit a at its west end, b at its east end."""
    (tmp_path / "line.map").write_text(format_map(GridMap.from_rows(["..."])), encoding="utf-8")
    (tmp_path / "line.toml").write_text(
        'map = "line.map"\n'
        '[[units]]\nid = "a"\nstart = [0, 0]\ncapacity = 1.0\n'
        '[[units]]\nid = "b"\nstart = [2, 0]\ncapacity = 1.0\n',
        encoding="utf-8",
    )
    return load_scenario(tmp_path / "line.toml")


def _unit_a(path: Path, handle: SharedHandle, told: Queue[object], go: Event) -> None:
    """Another process: a steps east into the middle; after b's try, what a sees and counts."""
    world = SharedWorld.attach(load_scenario(path), handle)
    try:
        with world.turn():
            told.put(world.move("a", Direction.E))
        go.wait(20)
        with world.turn():
            told.put((world.sense("a")[Direction.E], world.prevented, world.moves["b"]))
    finally:
        world.close()


def test_one_world_across_processes_sees_every_unit_and_counts_every_refusal(
    tmp_path: Path,
) -> None:
    scenario = _line(tmp_path)
    context = multiprocessing.get_context("spawn")
    world = SharedWorld.create(scenario, context.Lock())
    told: Queue[object] = context.Queue()
    go = context.Event()
    other = context.Process(target=_unit_a, args=(scenario.path, world.handle, told, go))
    other.start()
    try:
        assert told.get(timeout=30) is True  # a moved, in the other process
        assert world.position("a") == Cell(1, 0)  # and this process sees it there
        with world.turn():
            assert world.sense("b")[Direction.W] == "unit"
            assert world.move("b", Direction.W) is False  # into a's square: refused...
        assert world.prevented == 1  # ...and counted
        assert world.position("b") == Cell(2, 0)
        go.set()
        assert told.get(timeout=30) == ("unit", 1, 0)  # the same world, seen from a's process
        other.join(20)
        assert other.exitcode == 0
    finally:
        if other.is_alive():
            other.kill()
        world.close(unlink=True)
    assert not Path("/dev/shm", world.handle.name.lstrip("/")).exists()  # nothing left behind


def test_a_shared_world_is_not_pickled_whole(tmp_path: Path) -> None:
    world = SharedWorld.create(_line(tmp_path), multiprocessing.get_context("spawn").Lock())
    try:
        with pytest.raises(TypeError, match="handle"):
            pickle.dumps(world)
    finally:
        world.close(unlink=True)


def _workers(pid: int) -> list[psutil.Process] | None:
    """The unit workers of the fleet process `pid`, once both run."""
    found = [p for p in psutil.Process(pid).children() if "spawn_main" in " ".join(p.cmdline())]
    return found if len(found) == 2 else None


def _robots(url: str, root: str, truth: Path, *extra: str) -> subprocess.Popen[bytes]:
    argv = ["robots", "--broker", url, "--root", root, "--scenario", str(PLAYFIELD)]
    argv += ["--step", str(STEP_S), "--truth", str(truth), *extra]
    return subprocess.Popen([sys.executable, "-m", "gridfleet", *argv], stderr=subprocess.PIPE)


@pytest.mark.timeout(120)
def test_a_sharded_fleet_does_every_job_and_the_stop_reaches_every_shard(
    broker: BrokerThread, probe_factory: Callable[..., MqttProbe], root: str, tmp_path: Path
) -> None:
    scenario = load_scenario(PLAYFIELD)
    units = [u.id for u in scenario.units]
    truth = tmp_path / "truth.jsonl"
    op = OperatorPeer(probe_factory(), Topics(root), "tester")
    fleet = _robots(broker.url, root, truth, "--workers", "2")
    coordinator = coordinator_thread(
        scenario, broker.url, root=root, step_s=STEP_S, db_path=tmp_path / "jobs.db"
    ).start(30)
    try:
        workers = wait_for(lambda: _workers(fleet.pid), 30, what="two unit workers")
        wait_for(lambda: all(op.last_state(u) for u in units), 30, what="every unit's state")
        jobs = [
            op.submit_job(Cell(1, 1), Cell(8, 8), 1.0, job_id="j1"),
            op.submit_job(Cell(8, 1), Cell(1, 8), 1.0, job_id="j2"),
            op.submit_job(Cell(5, 5), Cell(0, 9), 1.0, job_id="j3"),
        ]
        assert all(r.accepted for r in jobs)
        wait_for(lambda: op.all_final(["j1", "j2", "j3"]), 60, what="every job final")
        assert {j.state for j in op.listed_jobs().values()} == {"done"}
        # The stop, engaged once, holds the units of both processes.
        seen = {u: len(op.states(u)) for u in units}
        op.engage("shards test")

        def stopped(unit: str) -> bool:
            return any(s.estop and s.status == "stopped" for s in op.states(unit)[seen[unit] :])

        wait_for(lambda: all(stopped(u) for u in units), 10, what="every unit stopped")
        op.release("shards test")
    finally:
        coordinator.stop(30)
        fleet.send_signal(signal.SIGTERM)
        code = fleet.wait(30)
    assert code == 0, fleet.stderr.read().decode() if fleet.stderr else code
    last = json.loads(truth.read_text(encoding="utf-8").splitlines()[-1])
    assert last["moves"] > 0 and last["prevented"] == 0 and last["collisions"] == 0
    assert all(not p.is_running() for p in workers)  # every worker ended with the fleet
