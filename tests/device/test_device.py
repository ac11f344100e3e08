"""The virtual device over a real broker: LEDs follow the unit, its stop reaches everyone."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import threading
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import asynccontextmanager

import pytest

from gridfleet.device.shell import DeviceShell
from gridfleet.protocol import ErrorReport, Leds, Topics, decode, decode_estop, decode_press
from gridfleet.system.broker_thread import BrokerThread

from support.cli import gridfleet
from support.probe import MqttProbe
from support.wait import async_wait_for, wait_for

ALL = Leds(N=True, E=True, S=True, W=True)


@asynccontextmanager
async def running(device: DeviceShell) -> AsyncIterator[DeviceShell]:
    """Run `device` in the test's loop until the block ends; it must end cleanly."""
    stop = asyncio.Event()
    task = asyncio.create_task(device.run(stop))
    try:
        await async_wait_for(lambda: device.online or task.done(), what="device online")
        assert not task.done(), task.exception()
        yield device
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)


async def test_leds_follow_the_units_direction(
    broker: BrokerThread, topics: Topics, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    unit = probe_factory()  # plays unit1, publishing its direction as a unit does
    async with running(DeviceShell(broker.url, "unit1", root)) as device:
        assert device.leds == Leds()
        for side in ["N", "E", "S", "W", "-", "E"]:
            unit.publish(topics.unit("direction", "unit1"), side, qos=0, retain=True)
            expected = Leds() if side == "-" else Leds(**{side: True})
            await async_wait_for(lambda e=expected: device.leds == e, what=f"LEDs for {side}")
        # Another unit's direction is not ours.
        unit.publish(topics.unit("direction", "unit2"), "N", qos=0, retain=True)
        unit.publish(topics.unit("direction", "unit1"), "S", qos=0, retain=True)
        await async_wait_for(lambda: device.leds == Leds(S=True), what="LEDs for S")


async def test_retained_direction_is_shown_on_connect(
    broker: BrokerThread, topics: Topics, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    probe_factory().publish(topics.unit("direction", "unit3"), "W", qos=0, retain=True)
    async with running(DeviceShell(broker.url, "unit3", root)) as device:
        await async_wait_for(lambda: device.leds == Leds(W=True), what="retained direction")


async def test_stop_key_engages_a_retained_valid_estop_everyone_sees(
    broker: BrokerThread, topics: Topics, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    press = topics.device("device_stop", "dev-a")
    watcher = probe_factory()
    watcher.subscribe(press, qos=1)
    watcher.subscribe(topics.device("device_connection", "dev-a"), qos=1)
    async with running(DeviceShell(broker.url, "unit1", root, device_id="dev-a")) as device:
        await async_wait_for(
            lambda: watcher.received(topics.device("device_connection", "dev-a")),
            what="online",
        )
        unit = probe_factory()
        unit.publish(topics.unit("direction", "unit1"), "N", qos=0, retain=True)
        await async_wait_for(lambda: device.leds == Leds(N=True), what="LED N")
        device.press()
        assert device.leds == ALL  # the press shows at once
        seen = await async_wait_for(lambda: watcher.received(press), what="the press")
        signal_ = decode_press(seen[0].payload, "dev-a")
        assert signal_ is not None and signal_.reason == "button"
        await async_wait_for(lambda: not device.core.pending_stop, what="stop confirmed")
        assert device.core.pressed and device.leds == ALL
        # A client arriving later gets it as the retained value.
        late = probe_factory()
        late.subscribe(press, qos=1)
        retained = await async_wait_for(lambda: late.received(press), what="retained press")
        assert retained[0].retain and decode_press(retained[0].payload, "dev-a") is not None
        # Released by the operator, then the press cleared (the coordinator's part, played here).
        unit.publish(topics.fleet("estop"), "released|dashboard|checked", qos=1, retain=True)
        unit.publish(press, "", qos=1, retain=True)
        await async_wait_for(lambda: device.leds == Leds(N=True), what="released")
    # Exactly one press was sent (then the clearing); the clean exit said offline.
    await async_wait_for(lambda: len(watcher.received(press)) >= 2, what="the watcher sees both")
    assert [m.payload for m in watcher.received(press)] == [b"engaged|dev-a|button", b""]
    conn = topics.device("device_connection", "dev-a")
    await async_wait_for(lambda: [m.payload for m in watcher.received(conn)][-1:] == [b"offline"])
    assert [m.payload for m in watcher.received(conn)] == [b"online", b"offline"]


async def test_bad_payloads_change_nothing_and_are_reported(
    broker: BrokerThread, topics: Topics, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    probe = probe_factory()
    probe.subscribe(topics.fleet("errors"), qos=1)
    async with running(DeviceShell(broker.url, "unit1", root, device_id="dev-b")) as device:
        probe.publish(topics.unit("direction", "unit1"), "E", qos=0, retain=True)
        probe.publish(topics.fleet("estop"), "released|dashboard|ok", qos=1, retain=True)
        await async_wait_for(lambda: device.leds == Leds(E=True) and device.core.estop is not None)
        bad = [
            (topics.unit("direction", "unit1"), b"north"),
            (topics.unit("direction", "unit1"), b"N" * 70_000),
            (topics.fleet("estop"), b"engaged"),
            (topics.fleet("estop"), b"engaged|not an id|x"),
            (topics.fleet("estop"), b"engaged|x|" + b"y" * 1000),
            (topics.device("device_stop", "dev-b"), b"released|dev-b|button"),
            (topics.device("device_stop", "dev-b"), b"engaged|someone|x"),
        ]
        for topic, payload in bad:
            probe.publish(topic, payload, qos=1, retain=True)
        reports = await async_wait_for(
            lambda: (r := probe.received(topics.fleet("errors"))) and len(r) >= len(bad) and r,
            what="error reports",
        )
        for report in reports:
            decoded = decode(ErrorReport, report.payload)
            assert decoded.header.sender == "dev-b" and decoded.reason
        assert device.leds == Leds(E=True)
        assert not device.core.estop_engaged and not device.core.pending_stop
        assert len(device.refused) == len(bad)


@pytest.mark.every_broker  # a broker restarted
async def test_press_while_broker_is_down_is_sent_after_reconnect(
    fresh_broker: BrokerThread, root: str
) -> None:
    topics = Topics(root)
    async with running(DeviceShell(fresh_broker.url, "unit1", root, device_id="dev-c")) as dev:
        await asyncio.to_thread(fresh_broker.stop)
        await async_wait_for(lambda: not dev.online, what="device notices the broker is gone")
        dev.press()
        assert dev.leds == ALL
        await asyncio.to_thread(fresh_broker.start)
        with MqttProbe(fresh_broker.url) as probe:
            press = topics.device("device_stop", "dev-c")
            probe.subscribe(press, qos=1)
            seen = await async_wait_for(
                lambda: probe.received(press), timeout=20, what="stop after restart"
            )
            assert decode_press(seen[0].payload, "dev-c") == decode_estop(b"engaged|dev-c|button")
            await async_wait_for(lambda: not dev.core.pending_stop, what="confirmed")


# -- the `gridfleet device` command ----------------------------------------------------------------


class Proc:
    """`gridfleet device` in a subprocess, its stdout collected line by line."""

    def __init__(self, *args: str, stdin: int = subprocess.PIPE) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.p = subprocess.Popen(
            [sys.executable, "-m", "gridfleet", "device", *args],
            stdin=stdin,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
        )
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()

    def _read(self) -> None:
        assert self.p.stdout is not None
        for raw in self.p.stdout:
            self.lines.append(raw.decode().rstrip("\n"))

    def wait_line(self, needle: str, timeout: float = 15.0) -> str:
        found = wait_for(
            lambda: next((x for x in self.lines if needle in x), None),
            timeout,
            what=f"{needle!r} in output {self.lines[-3:]}",
        )
        assert found is not None
        return found

    def send(self, text: str) -> None:
        assert self.p.stdin is not None
        self.p.stdin.write(text.encode())
        self.p.stdin.flush()


@pytest.fixture
def proc_factory() -> Iterator[Callable[..., Proc]]:
    made: list[Proc] = []

    def make(*args: str, stdin: int = subprocess.PIPE) -> Proc:
        made.append(Proc(*args, stdin=stdin))
        return made[-1]

    yield make
    for proc in made:
        if proc.p.poll() is None:
            proc.p.kill()
            proc.p.wait(10)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_device_command_shows_leds_stops_and_exits_cleanly(
    broker: BrokerThread,
    topics: Topics,
    root: str,
    probe_factory: Callable[..., MqttProbe],
    proc_factory: Callable[..., Proc],
    sig: signal.Signals,
) -> None:
    press = topics.device("device_stop", "device-unit7")
    watcher = probe_factory()
    watcher.subscribe(press, qos=1)
    conn = topics.device("device_connection", "device-unit7")
    watcher.subscribe(conn, qos=1)
    proc = proc_factory("--broker", broker.url, "--unit", "unit7", "--root", root)
    proc.wait_line("link=online")
    watcher.publish(topics.unit("direction", "unit7"), "S", qos=0, retain=True)
    proc.wait_line("leds=..#. direction=S")
    proc.send("s\n")
    stop = watcher.wait(press)
    assert decode_press(stop.payload, "device-unit7") == decode_estop(
        b"engaged|device-unit7|button"
    )
    proc.wait_line("leds=#### direction=S estop=engaged")
    proc.p.send_signal(sig)
    assert proc.p.wait(15) == 0
    assert proc.p.stderr is not None and "Traceback" not in proc.p.stderr.read().decode()
    watcher.wait(conn, lambda m: m.payload == b"offline")
    assert len(watcher.received(press)) == 1


def test_device_command_with_stdin_from_dev_null_runs_without_keys(
    broker: BrokerThread, root: str, proc_factory: Callable[..., Proc]
) -> None:
    # As under a service manager: no terminal and no pipe to read keys from.
    proc = proc_factory(
        "--broker", broker.url, "--unit", "u9", "--root", root, stdin=subprocess.DEVNULL
    )
    proc.wait_line("link=online")
    proc.p.send_signal(signal.SIGINT)
    assert proc.p.wait(15) == 0
    assert proc.p.stderr is not None and "Traceback" not in proc.p.stderr.read().decode()


@pytest.mark.every_broker  # the broker sends the will
def test_device_command_killed_leaves_its_last_will(
    broker: BrokerThread,
    topics: Topics,
    root: str,
    probe_factory: Callable[..., MqttProbe],
    proc_factory: Callable[..., Proc],
) -> None:
    watcher = probe_factory()
    conn = topics.device("device_connection", "dev-k")
    watcher.subscribe(conn, qos=1)
    proc = proc_factory(
        "--broker", broker.url, "--unit", "unit1", "--root", root, "--device-id", "dev-k"
    )
    proc.wait_line("link=online")
    proc.p.kill()
    proc.p.wait(10)
    watcher.wait(conn, lambda m: m.payload == b"broken")


def test_device_command_refuses_bad_ids() -> None:
    out = gridfleet("device", "--unit", "bad/id", timeout=30)
    assert out.returncode == 2
    assert "unit id" in out.stderr and "Traceback" not in out.stderr


def test_device_command_on_a_terminal_highlights_the_lit_arrow_and_quits_on_q(
    broker: BrokerThread, topics: Topics, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    import pty
    import select

    main_fd, tty_fd = pty.openpty()
    p = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "gridfleet",
            "device",
            "--broker",
            broker.url,
            "--unit",
            "unit1",
            "--root",
            root,
        ],
        stdin=tty_fd,
        stdout=tty_fd,
        stderr=subprocess.PIPE,
    )
    os.close(tty_fd)
    seen = bytearray()

    def screen_has(needle: bytes) -> bool:
        while select.select([main_fd], [], [], 0)[0]:
            try:
                seen.extend(os.read(main_fd, 65536))
            except OSError:
                break
        return needle in seen

    try:
        probe = probe_factory()
        wait_for(lambda: screen_has(b"unit unit1") or p.poll() is not None, 15)
        assert p.poll() is None
        probe.publish(topics.unit("direction", "unit1"), "E", qos=0, retain=True)
        lit_east = "\x1b[1;42;30m \u2192 \x1b[0m".encode()
        wait_for(lambda: screen_has(lit_east), 15, what="the east arrow highlighted")
        os.write(main_fd, b"q")
        assert p.wait(15) == 0
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(10)
        os.close(main_fd)
