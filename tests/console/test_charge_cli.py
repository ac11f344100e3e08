"""`gridfleet job charge UNIT`: sends `control_unit` "charge" and prints the coordinator's answer
(a refusal in one line, exit 1), as the other unit controls do. The test plays the coordinator."""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import pytest

from gridfleet.protocol import ControlUnit, Topics, decode
from gridfleet.system.broker_thread import BrokerThread

from support.cli import gridfleet
from support.fleet_peer import CoordinatorPeer
from support.probe import MqttProbe


@pytest.fixture
def coordinator(probe_factory: Callable[..., MqttProbe], topics: Topics) -> CoordinatorPeer:
    """An online coordinator's status, and a probe that hears the requests."""
    probe = probe_factory()
    probe.subscribe(topics.request("control_unit"))
    peer = CoordinatorPeer(probe, topics)
    peer.status("online")
    return peer


def charge(
    pool: ThreadPoolExecutor, broker: BrokerThread, root: str, unit: str
) -> Future[subprocess.CompletedProcess[str]]:
    """`gridfleet job charge UNIT`, running while the test answers it."""
    args = ("job", "charge", unit, "--broker", broker.url, "--root", root, "--timeout", "20")
    return pool.submit(gridfleet, *args)


def answer(coordinator: CoordinatorPeer, topics: Topics, unit: str, reason: str | None) -> None:
    """Answer the charge request for `unit`: accepted without a reason, else refused."""
    seen = coordinator.probe.wait(
        topics.request("control_unit"),
        lambda m: decode(ControlUnit, m.payload).unit == unit,
        timeout=30,
    )
    request = decode(ControlUnit, seen.payload)
    assert request.command == "charge" and request.reply_to is not None
    coordinator.reply(request.reply_to, request.request_id, reason is None, reason)


def test_charge_is_sent_and_its_answer_printed(
    broker: BrokerThread, root: str, topics: Topics, coordinator: CoordinatorPeer
) -> None:
    with ThreadPoolExecutor(1) as pool:
        running = charge(pool, broker, root, "unit2")
        answer(coordinator, topics, "unit2", None)
        done = running.result(timeout=60)
    assert (done.returncode, done.stdout, done.stderr) == (0, "accepted\n", "")


def test_a_refused_charge_is_one_line_and_exit_1(
    broker: BrokerThread, root: str, topics: Topics, coordinator: CoordinatorPeer
) -> None:
    why = "unit unit4 reports no energy: it never runs down"
    with ThreadPoolExecutor(1) as pool:
        running = charge(pool, broker, root, "unit4")
        answer(coordinator, topics, "unit4", why)
        done = running.result(timeout=60)
    assert (done.returncode, done.stdout) == (1, f"refused: {why}\n")


def test_a_bad_unit_id_is_one_line_before_anything_is_sent() -> None:
    done = gridfleet("job", "charge", "no such unit!")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "unit id" in done.stderr.strip().splitlines()[-1]
