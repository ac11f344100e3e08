"""A component stopped cleanly while messages still flow to it leaves `offline`, never its will.

A message arriving as a client's socket closes turns the close into a TCP reset, which can drop
the DISCONNECT; the broker then publishes the client's last will ("broken") over the `offline`
it had just sent, and a dashboard opened later shows a broken unit that was stopped on purpose.
Each component here is stopped several times under a flood of (harmless) estop releases.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path

import pytest

from coordinator.service import Coordinator
from gridfleet.bus import make_client
from gridfleet.device import VirtualDevice
from gridfleet.protocol import (
    Connection,
    CoordinatorStatus,
    EstopSignal,
    Topics,
    decode,
    encode_estop,
)
from gridfleet.scenario import load_scenario
from gridfleet.testing.broker_thread import BrokerThread
from gridfleet.testing.probe import MqttProbe
from gridfleet.testing.wait import async_wait_for
from robots.fleet import Fleet

MAPS = Path(__file__).resolve().parent.parent / "maps"
ROUNDS = 8  # without the fix about 4 in 10 stops ended "broken": 8 clean rounds in a row prove it
Started = tuple[Callable[[asyncio.Event], Awaitable[None]], Callable[[], bool]]


@contextlib.asynccontextmanager
async def flooding(url: str, topics: Topics) -> AsyncIterator[None]:
    """Estop releases at QoS 0 as fast as one client sends them (each is a no-op to everyone)."""
    payload = encode_estop(EstopSignal(False, "flood", "test"))
    stop = asyncio.Event()
    async with make_client(url, "flooder") as client:

        async def flood() -> None:
            while not stop.is_set():
                for _ in range(20):
                    await client.publish(topics.fleet("estop"), payload, qos=0)
                await asyncio.sleep(0)  # let the component under test run between bursts

        task = asyncio.create_task(flood())
        try:
            yield
        finally:
            stop.set()
            await task


async def last_retained(url: str, topic: str) -> bytes:
    """The retained message on `topic`, as a client connecting now gets it."""
    with MqttProbe(url) as probe:
        await asyncio.to_thread(probe.subscribe, topic)
        seen = await async_wait_for(lambda: probe.received(topic), what=f"retained {topic}")
        return seen[-1].payload


def make_unit(url: str, root: str, tmp_path: Path) -> Started:
    fleet = Fleet(load_scenario(MAPS / "playfield.toml"), url, root=root, units=["unit1"])
    return fleet.run, fleet.ready.is_set


def make_coordinator(url: str, root: str, tmp_path: Path) -> Started:
    grid = load_scenario(MAPS / "playfield.toml").grid
    coordinator = Coordinator(url, grid, root=root, step_s=0.05, db_path=tmp_path / "jobs.db")
    return coordinator.run, coordinator.ready.is_set


def make_device(url: str, root: str, tmp_path: Path) -> Started:
    device = VirtualDevice(url, "unit1", root, device_id="dev-goodbye")
    return device.run, lambda: device.online


def unit_said(payload: bytes) -> str:
    return decode(Connection, payload).state


def coordinator_said(payload: bytes) -> str:
    return decode(CoordinatorStatus, payload).state


CASES = {
    "unit": (make_unit, lambda t: t.unit("connection", "unit1"), unit_said),
    "coordinator": (make_coordinator, lambda t: t.fleet("coordinator"), coordinator_said),
    "device": (
        make_device,
        lambda t: t.device("device_connection", "dev-goodbye"),
        lambda p: p.decode(),
    ),
}


async def stop_under_traffic(component: str, url: str, root: str, tmp_path: Path) -> str:
    """Start `component`, stop it while the flood reaches it; what its connection topic keeps."""
    make, topic_of, said = CASES[component]
    topics = Topics(root)
    run, ready = make(url, root, tmp_path)
    stop = asyncio.Event()
    task = asyncio.create_task(run(stop))
    await async_wait_for(lambda: ready() or task.done(), what=f"{component} ready")
    assert not task.done(), task.exception()
    async with flooding(url, topics):
        stop.set()
        await asyncio.wait_for(task, 10)
    return said(await last_retained(url, topic_of(topics)))


@pytest.mark.parametrize("component", CASES)
async def test_a_clean_stop_under_traffic_leaves_offline_not_the_will(
    component: str, broker: BrokerThread, root: str, tmp_path: Path
) -> None:
    ended = [await stop_under_traffic(component, broker.url, root, tmp_path) for _ in range(ROUNDS)]
    assert ended == ["offline"] * ROUNDS
