"""`gridfleet bench vda5050`: a mixed fleet on one broker, gridfleet's units and VDA 5050 vehicles.

The playfield's first `--units` simulated units and `--vehicles` VDA 5050 2.1.0 vehicles of our
own (robots/vda5050/virtual.py, through the adapter) share the jobs for `--minutes`, random jobs
kept queued; then the fleet's stop is engaged `--stops` times. Reported: jobs done a minute (and
how many by the vehicles), and the time from the stop's publish until every vehicle's own state
says it is paused (the adapter's `startPause` there and back), median and p99.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from gridfleet.broker.embedded import BrokerSettings
from gridfleet.bus import connect_first
from gridfleet.console.feed import random_job
from gridfleet.console.operator import operator_session
from gridfleet.endpoint import payload_of
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.paths import DistanceFieldCache
from gridfleet.protocol import Topics
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.shell import AdapterShell
from gridfleet.robots.vda5050.virtual import VirtualSpec
from gridfleet.robots.vda5050.virtual_shell import VirtualVehicleShell
from gridfleet.robots.vda5050.wire import Vehicle
from gridfleet.scenario import Scenario, UnitSpec, load_scenario
from gridfleet.shipped import shipped_file
from gridfleet.system.assembly import Assembly, SystemSpec
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import S, ServiceThread

PLAYFIELD = shipped_file("playfield", ".toml")  # the checkout's maps/, or a wheel's
FRAME = Frame("bench")
ROOT = "bench-vda5050"
PAUSED_WAIT_S = 10.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet bench vda5050`."""
    parser.add_argument("--units", type=int, default=2, help="gridfleet's units (1-4, default 2)")
    parser.add_argument("--vehicles", type=int, default=2, help="VDA 5050 vehicles (default 2)")
    parser.add_argument("--minutes", type=float, default=1.0, help="the jobs phase (default 1)")
    parser.add_argument("--stops", type=int, default=20, help="stops to time (default 20)")
    parser.add_argument("--step", type=float, default=0.1, help="step period (default 0.1 s)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")


def mixed_scenario(units: int, vehicles: int, seed: int) -> tuple[Scenario, list[Cell]]:
    """The playfield's first `units` units (no hidden obstacles: a vehicle has no sensor of
    gridfleet's to find one), and a free square for each vehicle."""
    if not 1 <= units <= 4 or not 1 <= vehicles <= 20:
        raise ConfigError("--units 1 to 4 (the playfield's), --vehicles 1 to 20")
    base = load_scenario(PLAYFIELD)
    kept: list[UnitSpec] = list(base.units[:units])
    taken = {u.start for u in kept}
    free = [c for c in base.grid.free_cells() if c not in taken]
    squares = random.Random(seed).sample(free, vehicles)
    return replace(base, units=tuple(kept), hidden_obstacles=(), jobs=(), goals=()), squares


async def _paused_listener(
    url: str, serials: set[str], seen: list[tuple[float, str, bool]]
) -> None:
    """Every vehicle state's `paused`, with when it arrived."""
    async with connect_first(url, f"bench-vda-listen-{random.randrange(10**6)}") as client:
        await client.subscribe("uagv/v2/bench/+/state", qos=0)
        async for message in client.messages:
            serial = str(message.topic).split("/")[3]
            if serial in serials:
                state = json.loads(payload_of(message))
                seen.append((time.monotonic(), serial, bool(state.get("paused"))))


async def _drive(
    url: str, scenario: Scenario, args: argparse.Namespace, serials: set[str]
) -> dict[str, Any]:
    topics = Topics(ROOT)
    seen: list[tuple[float, str, bool]] = []
    listener = asyncio.create_task(_paused_listener(url, serials, seen))
    rng = random.Random(args.seed)
    fields = DistanceFieldCache(scenario.grid)
    async with operator_session(url, topics, "bench-vda") as op:
        ids = [u.id for u in scenario.units] + [f"agv{n}" for n in range(1, args.vehicles + 1)]
        await op.wait_for_units(ids, timeout=60)
        submitted = 0
        end = time.monotonic() + 60 * args.minutes
        while time.monotonic() < end:
            queued = sum(1 for j in (op.jobs.jobs if op.jobs else []) if j.state == "queued")
            if queued < len(ids):
                pickup, dropoff, mass = random_job(scenario, rng, fields)
                job_id = f"b{submitted + 1}"
                if (await op.submit_job(pickup, dropoff, min(mass, 3.0), job_id)).accepted:
                    submitted += 1
            else:
                await asyncio.sleep(0.1)
        view = op.jobs
        done = [j for j in (view.listed() if view else []) if j.state == "done"]
        counts = view.counts if view else {}
        stops_ms: list[float] = []
        for _ in range(args.stops):
            mark = len(seen)
            t0 = time.monotonic()
            await op.set_estop(True, "bench")
            paused: dict[str, float] = {}
            while len(paused) < len(serials) and time.monotonic() - t0 < PAUSED_WAIT_S:
                for at, serial, is_paused in seen[mark:]:
                    if is_paused and serial not in paused:
                        paused[serial] = at
                await asyncio.sleep(0.005)
            if len(paused) == len(serials):
                stops_ms.append(1000 * (max(paused.values()) - t0))
            await op.set_estop(False, "bench")
            mark = len(seen)
            t1 = time.monotonic()
            resumed: set[str] = set()
            while len(resumed) < len(serials) and time.monotonic() - t1 < PAUSED_WAIT_S:
                resumed |= {s for _, s, p in seen[mark:] if not p}
                await asyncio.sleep(0.01)
    listener.cancel()
    by_vehicles = sum(1 for j in done if j.unit is not None and j.unit.startswith("agv"))
    ordered = sorted(stops_ms)
    return {
        "units": args.units,
        "vehicles": args.vehicles,
        "minutes": args.minutes,
        "jobs_done": counts.get("done", 0),
        "jobs_per_minute": round(counts.get("done", 0) / args.minutes, 1),
        # Of the latest finished jobs the queue view lists (up to 20), how many the vehicles did.
        "latest_done": len(done),
        "latest_done_by_vehicles": by_vehicles,
        "stops_timed": len(stops_ms),
        "stops_missed": args.stops - len(stops_ms),
        "stop_to_all_paused_ms_p50": round(statistics.median(ordered), 1) if ordered else None,
        "stop_to_all_paused_ms_p99": round(ordered[max(0, round(0.99 * len(ordered)) - 1)], 1)
        if ordered
        else None,
        "stop_to_all_paused_ms_max": round(ordered[-1], 1) if ordered else None,
    }


def _given(service: S) -> Callable[[], S]:
    """A ServiceThread's maker for a service made already."""
    return lambda: service


def run(args: argparse.Namespace) -> int:
    """Run the mixed fleet, measure, print; exit 1 when a stop did not pause every vehicle."""
    scenario, squares = mixed_scenario(args.units, args.vehicles, args.seed)
    with (
        tempfile.TemporaryDirectory() as tmp,
        BrokerThread(BrokerSettings(port=0, ws_port=None)) as broker,
    ):
        spec = SystemSpec(
            scenario, broker=broker.url, root=ROOT, step_s=args.step, db_path=Path(tmp) / "jobs.db"
        )
        assembly = Assembly(spec, "threads")
        assembly.start_threads()
        threads: list[ServiceThread[Any]] = []
        try:
            configs = []
            for n, square in enumerate(squares, start=1):
                vehicle = Vehicle(f"agv{n}", "bench", f"v{n}", "2.1.0")
                configs.append(VehicleConfig(vehicle, FRAME, None, 0.0, False))
                spec_v = VirtualSpec(
                    FRAME.position(square), FRAME.map_id, speed=1.0, capacity_kg=3.0, action_s=0.2
                )
                shell = VirtualVehicleShell(vehicle, spec_v, broker.url)
                threads.append(ServiceThread(_given(shell), f"vehicle-{n}").start())
            adapter = AdapterShell(
                configs, scenario.grid, broker.url, Topics(ROOT), step_s=args.step
            )
            threads.append(ServiceThread(_given(adapter), "vda5050").start())
            serials = {c.vehicle.serial_number for c in configs}
            figures = asyncio.run(_drive(broker.url, scenario, args, serials))
        finally:
            for thread in reversed(threads):
                thread.stop()
            assembly.stop()
    if args.json:
        print(json.dumps(figures))
    else:
        for key, value in figures.items():
            print(f"{key}: {value}")
    return 0 if figures["stops_missed"] == 0 else 1
