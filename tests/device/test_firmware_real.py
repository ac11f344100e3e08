"""The ESP32 sketch built on the host against the real PubSubClient 2.8 and ArduinoCore-API 1.5.2
(only the board core is a stand-in), run over real sockets against the embedded amqtt broker and
Debian's Mosquitto: what it sends is read off the wire by a relay, what it shows off its LED pins."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Protocol

import pytest

from gridfleet.system.broker_thread import BrokerThread

from support.firmware_libs import compiler_warnings, firmware_libs, make_env
from support.mosquitto import MosquittoBroker
from support.mqtt_tap import MqttTap, Packet
from support.paths import REPO
from support.probe import MqttProbe, Seen
from support.wait import wait_for

FW = REPO / "firmware"
FIRMWARE_LIBS = firmware_libs()
MAX_ROOT_BYTES = 234  # firmware/esp32_unit/src/protocol.h: kMaxRootBytes (its unit test checks it)
STOP_RETRY_MS = 2000  # config.example.h: GF_STOP_RETRY_MS
CONNECT, PUBLISH, PUBACK, SUBSCRIBE = 1, 3, 4, 8

pytestmark = [
    pytest.mark.skipif(
        not FIRMWARE_LIBS.is_dir(),
        reason=f"no {FIRMWARE_LIBS} (PubSubClient, ArduinoCore-API): real-library tests not run",
    ),
    pytest.mark.skipif(
        shutil.which("g++") is None or not Path("/usr/include/doctest/doctest.h").exists(),
        reason="needs g++ and doctest-dev (.ci/run installs them)",
    ),
    pytest.mark.slow,  # make test-fast leaves them out: a build and real brokers
    pytest.mark.firmware,  # make test runs them in the firmware lane
]


class Broker(Protocol):
    """What BrokerThread and MosquittoBroker both offer."""

    @property
    def port(self) -> int: ...
    @property
    def url(self) -> str: ...
    def start(self, timeout: float = 10.0) -> None: ...
    def stop(self, timeout: float = ...) -> None: ...


@pytest.fixture(scope="module")
def device_host(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sketch as a host program (firmware/host_test/real/device_main.cpp), built afresh."""
    build = tmp_path_factory.mktemp("firmware-build")
    out = subprocess.run(
        [
            "make",
            "-C",
            str(FW),
            "-j2",
            f"BUILD={build}",
            f"FIRMWARE_LIBS={FIRMWARE_LIBS}",
            "device-host",
        ],
        capture_output=True,
        text=True,
        timeout=240,
        env=make_env(),
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert compiler_warnings(out.stdout + out.stderr) == []
    return build / "real3" / "device_host"


@pytest.fixture(params=["amqtt", "mosquitto"])
def real_broker(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Broker]:
    """A broker of this test's own on a free port: the embedded amqtt, or Debian's Mosquitto."""
    broker: BrokerThread | MosquittoBroker
    if request.param == "mosquitto":
        broker = MosquittoBroker(tmp_path_factory.mktemp("mosquitto"))
    else:
        broker = BrokerThread()
    broker.start()
    try:
        yield broker
    finally:
        broker.stop()


class Device:
    """The host program running: commands in, its output lines (with arrival times) out."""

    def __init__(self, binary: Path, env: dict[str, str]) -> None:
        self.proc = subprocess.Popen(
            [str(binary)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            env={**os.environ, **env},
        )
        self._lines: list[str] = []
        self._lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._lock:
                self._lines.append(line.rstrip("\n"))

    def lines(self, prefix: str = "") -> list[str]:
        """Output lines so far starting with `prefix`."""
        with self._lock:
            return [line for line in self._lines if line.startswith(prefix)]

    def leds(self) -> str:
        """What the LEDs show now, N E S W (`.` for off)."""
        shown = self.lines("leds ")
        return shown[-1].split()[1] if shown else "...."

    def wait_leds(self, match: Callable[[str], bool], what: str, timeout: float = 20) -> None:
        """Wait until the LEDs show something `match` accepts."""
        wait_for(lambda: match(self.leds()), timeout, what=f"LEDs {what} (now {self.leds()})")

    def send(self, command: str) -> None:
        """A line on its stdin: press, release, wifi down, wifi up."""
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def close(self) -> None:
        """Quit it (kill it if it does not)."""
        try:
            self.send("quit")
            self.proc.wait(10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait(10)


def blinking(leds: str) -> bool:
    """The stop pattern: all four together (on or off)."""
    return leds in ("NESW", "....")


def long_root() -> str:
    """A topic root of this test's own, as long as the device accepts (the stop still fits)."""
    root = f"t/fw-{uuid.uuid4().hex[:8]}"
    while len(root) < MAX_ROOT_BYTES:
        root += "/" + "r" * min(60, MAX_ROOT_BYTES - len(root) - 1)
    assert len(root) == MAX_ROOT_BYTES
    return root


def stays(check: Callable[[], bool], seconds: float) -> bool:
    """Whether `check` holds all through the next `seconds` (a window to see nothing happen)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if not check():
            return False
        time.sleep(0.05)
    return check()


LOST = "[serial] gridfleet: MQTT: connection lost"
CONNECTED = "[serial] gridfleet: MQTT: connected as "
CONNECT_FAILED = "[serial] gridfleet: MQTT: connect failed"


def story(device: Device, tap: MqttTap) -> str:
    """What the device said and sent, for a failure's report."""
    sent = [f"#{p.connection} kind {p.kind} at {p.at:.2f}" for p in tap.packets()]
    return "\ndevice:\n" + "\n".join(device.lines("[serial]")) + "\nsent:\n" + "\n".join(sent)


def test_the_sketch_on_the_real_pubsubclient_over_real_sockets(
    device_host: Path, real_broker: Broker
) -> None:
    root = long_root()
    device_id = "dev-real"
    prefix = f"{root}/v1/"
    direction = f"{prefix}units/unit1/direction"
    estop = f"{prefix}fleet/estop"
    press = f"{prefix}devices/{device_id}/stop"
    connection = f"{prefix}devices/{device_id}/connection"
    pressed = f"engaged|{device_id}|button".encode()
    with MqttProbe(real_broker.url) as probe:
        probe.publish(direction, "E", retain=True)
        probe.publish(estop, "released|dashboard|ok", retain=True)
    tap = MqttTap(real_broker.port)
    device = Device(
        device_host,
        {
            "GF_HOST_MQTT_PORT": str(tap.port),
            "GF_HOST_ROOT": root,
            "GF_HOST_DEVICE": device_id,
            "GF_HOST_UNIT": "unit1",
        },
    )

    def sent(kind: int, connection_number: int | None = None) -> list[Packet]:
        return [
            p
            for p in tap.packets(kind)
            if connection_number is None or p.connection == connection_number
        ]

    def presses(connection_number: int | None = None) -> list[Packet]:
        return [p for p in sent(PUBLISH, connection_number) if p.publish_fields()[0] == press]

    def subscribed(connection_number: int) -> dict[str, int]:
        return {t: q for p in sent(SUBSCRIBE, connection_number) for t, q in p.subscriptions()}

    wanted = {direction: 0, estop: 0, press: 0}  # every subscription at QoS 0 (protocol.md §2)
    probe = MqttProbe(real_broker.url).connect()
    try:
        probe.subscribe(connection)
        probe.subscribe(press)
        # Connects with its last will: `broken`, retained, QoS 1, on its connection topic.
        wait_for(lambda: sent(CONNECT), 20, what="the device's CONNECT")
        assert sent(CONNECT)[0].connect_fields() == {
            "client_id": device_id,
            "clean": True,
            "will_topic": connection,
            "will_payload": "broken",
            "will_qos": 1,
            "will_retain": True,
        }
        # Subscribes to its direction, the fleet's stop and its own press.
        wait_for(lambda: subscribed(1) == wanted, 10, what=f"subscriptions {wanted}")
        probe.wait(connection, lambda m: m.payload == b"online")
        device.wait_leds(lambda s: s == ".E..", "showing E")
        probe.publish(direction, "S", retain=True)
        device.wait_leds(lambda s: s == "..S.", "showing S")

        # Messages too big for PubSubClient's buffer are dropped. They come at QoS 0, as all do
        # to a QoS 0 subscription: there is nothing to acknowledge, so the broker never waits on
        # the device (20 unacknowledged QoS 1 messages, Mosquitto's default, would stall it).
        with probe.batch():
            for _ in range(25):
                probe.publish(estop, "x" * 1000, qos=1)
        # The largest valid stop (512 bytes) at the longest root still arrives whole.
        reason = "€" * 164 + "ab"
        biggest = f"engaged|dashboard|{reason}"
        assert len(biggest.encode()) == 512
        probe.publish(estop, biggest, retain=True)
        device.wait_leds(lambda s: s == "NESW", "blinking for the stop")
        assert sent(PUBACK) == []
        probe.publish(estop, "released|dashboard|ok", retain=True)
        device.wait_leds(lambda s: s == "..S.", "back to S")

        # One press: one retained stop on its own press topic, confirmed, never re-sent.
        device.send("press")
        device.wait_leds(blinking, "blinking at the press")
        device.send("release")
        wait_for(lambda: presses(), 10, what="the press on the wire")
        assert presses()[0].publish_fields() == (press, pressed, 0, True)
        probe.wait(press, lambda m: m.payload == pressed)
        assert stays(lambda: len(presses()) == 1, STOP_RETRY_MS / 1000 + 1.5)
        # An operator releases; the coordinator clears the press.
        probe.publish(press, "", retain=True)
        device.wait_leds(lambda s: s == "..S.", "showing S after the release")
    finally:
        probe.close()

    # The broker goes down; a press meanwhile is sent once after it is back.
    real_broker.stop()
    # It may have connected again while the broker was closing (its clients go before its
    # port): a failed attempt since the broker is down says the device is offline now.
    before_outage = {p.connection for p in sent(CONNECT)}
    failed = len(device.lines(CONNECT_FAILED))
    wait_for(lambda: len(device.lines(CONNECT_FAILED)) > failed, 20, what="the outage")
    assert len(device.lines(LOST)) == len(device.lines(CONNECTED)), story(device, tap)
    device.send("press")
    device.wait_leds(blinking, "blinking at a press while offline")
    device.send("release")
    assert len(presses()) == 1
    real_broker.start()
    probe = MqttProbe(real_broker.url).connect()
    try:
        probe.subscribe(press)
        probe.subscribe(connection)

        def resubscribed() -> int | None:
            # An attempt while the broker was still starting may have failed: the session that
            # took is the one that subscribed again.
            later = sorted({p.connection for p in sent(CONNECT)} - before_outage)
            return next((c for c in later if subscribed(c) == wanted), None)

        # Reconnecting re-subscribes, each at its QoS, and sends the press once.
        def told() -> str:
            return story(device, tap)

        again = wait_for(resubscribed, 45, what="a reconnect that subscribes again", context=told)
        wait_for(lambda: presses(again), 30, what="the press after the outage", context=told)
        probe.wait(press, lambda m: m.payload == pressed)
        assert stays(lambda: len(presses()) == 2, STOP_RETRY_MS / 1000 + 1.5)
        assert len(presses(again)) == 1

        # WiFi drops while the socket still looks open: the next connect is a new session
        # (PubSubClient's connect() alone would reuse the old one and send no CONNECT).
        probe.wait(connection, lambda m: m.payload == b"online")
        before = len(sent(CONNECT))
        device.send("wifi down")
        probe.wait(connection, lambda m: m.payload == b"broken", timeout=20)  # the will
        device.send("wifi up")
        wait_for(lambda: len(sent(CONNECT)) > before, 20, what="a new CONNECT after WiFi")
        latest = max(p.connection for p in sent(CONNECT))
        wait_for(lambda: subscribed(latest) == wanted, 10, what="subscriptions after WiFi")
        probe.wait(
            connection,
            lambda m: m.payload == b"online" and m.at > probe_last(probe, connection, b"broken"),
        )
        serial = "\n".join(device.lines("[serial]"))
        assert "MQTT: connection lost" in serial and "WiFi: lost" in serial
    finally:
        probe.close()
        device.close()
        tap.close()


def probe_last(probe: MqttProbe, topic: str, payload: bytes) -> float:
    """When `payload` last arrived on `topic` (0 when never)."""
    seen: list[Seen] = [m for m in probe.received(topic) if m.payload == payload]
    return seen[-1].at if seen else 0.0


def test_a_dead_tls_broker_costs_each_attempt_at_most_the_bound_and_leds_and_button_live_on(
    device_host: Path,
) -> None:
    # The broker machine's port answers TCP (its kernel does) but nothing speaks TLS there: each
    # attempt waits for the handshake. arduino-esp32's own timeouts would stall the loop 120 s.
    dead = socket.create_server(("127.0.0.1", 0), backlog=8)
    device = Device(
        device_host, {"GF_HOST_MQTT_PORT": str(dead.getsockname()[1]), "GF_HOST_TLS": "1"}
    )
    try:
        wait_for(lambda: device.lines("ready "), 10, what="the device starting")
        bound_ms = int(device.lines("ready ")[0].split()[1])
        assert bound_ms <= 10000

        # Once the chase has lit two LEDs the first attempt is under way (it blocks for seconds).
        # What the LEDs showed before the press is what the test had seen when it pressed (CI runs
        # I and J: read back by the device's timestamps, the chase before it was one LED).
        def chase() -> list[str]:
            return [line.split()[1] for line in device.lines("leds ")]

        wait_for(lambda: len(set(chase()) - {"...."}) >= 2, 10, what="the offline chase")
        before = chase()
        device.send("press")

        def stalls() -> list[tuple[int, int]]:
            """(took, end) of each loop() pass stuck in an attempt, in ms of the device's clock."""
            return [(int(s.split()[1]), int(s.split()[2])) for s in device.lines("stall ")]

        def pressed_at() -> int:
            return int(device.lines("pressed ")[0].split()[1])

        # The attempt the press came in, and the one after it (the first two, unless this process
        # was held up for seconds: then whichever the press came in).
        wait_for(lambda: device.lines("pressed "), bound_ms / 1000 + 10, what="the press")
        wait_for(
            lambda: len([end for _, end in stalls() if end > pressed_at()]) >= 2,
            2 * bound_ms / 1000 + 10,
            what="2 tries after the press",
        )
        device.send("release")
    finally:
        device.close()
        dead.close()
    failed = [line for line in device.lines("[serial]") if "MQTT: connect failed" in line]
    assert len(failed) >= 2 and all("no TLS connection" in f and "timed out" in f for f in failed)
    leds = [(int(line.split()[2]), line.split()[1]) for line in device.lines("leds ")]
    pressed = pressed_at()
    tries = stalls()
    assert len(tries) >= 2
    for took, end in tries[:2]:
        # Each attempt costs the loop at most the bound (here the 5 s handshake timeout) ...
        assert took <= bound_ms
        # ... and meanwhile the LEDs keep going (a step every 250 ms), while loop() is stuck: at
        # least half the steps seen (the test's watcher of the pins polls, and on a loaded machine
        # it can miss one: 17 of 20 in one run).
        assert len([at for at, _ in leds if end - took < at < end]) >= took // 250 // 2
    during = next(i for i, (_, end) in enumerate(tries) if end > pressed)
    took, end = tries[during]
    assert end - took < pressed < end - 600, (tries, pressed)  # pressed mid-attempt
    # Before the press, the offline chase: one LED at a time, going round (from the first LED
    # lit: the device starts with all four dark).
    lit = before[next(i for i, shown in enumerate(before) if shown != "....") :]
    assert len(set(lit)) >= 2 and all(shown.count(".") == 3 for shown in lit), (leds, pressed)
    # The press shows the stop blink while the loop is still stuck in the attempt, and from
    # then on only the blink ...
    blink = next(at for at, shown in leds if shown == "NESW")
    assert pressed <= blink < end, (leds, pressed, end)
    assert {shown for at, shown in leds if blink <= at < end} == {"NESW", "...."}, leds
    # ... and the next attempt keeps showing it: the press is pending, not yet sent.
    took, end = tries[during + 1]
    assert {shown for at, shown in leds if end - took < at < end} == {"NESW", "...."}


def test_the_sketch_given_two_brokers_moves_to_the_second_when_the_first_dies(
    device_host: Path,
) -> None:
    root = f"t/fw-{uuid.uuid4().hex[:8]}"
    device_id = "dev-two"
    direction = f"{root}/v1/units/unit1/direction"
    connection = f"{root}/v1/devices/{device_id}/connection"
    with BrokerThread() as first, BrokerThread() as second:
        # Two brokers that share nothing: what the device shows after the move is the second's.
        for broker, shown in ((first, "E"), (second, "W")):
            with MqttProbe(broker.url) as probe:
                probe.publish(direction, shown, retain=True)
        one, two = f"127.0.0.1:{first.port}", f"127.0.0.1:{second.port}"  # known while up
        brokers = f"{one},mqtt://{two}"
        device = Device(
            device_host,
            {
                "GF_HOST_MQTT_BROKERS": brokers,
                "GF_HOST_ROOT": root,
                "GF_HOST_DEVICE": device_id,
                "GF_HOST_UNIT": "unit1",
            },
        )
        try:
            on_first = f"{CONNECTED}{device_id} to broker {one}"
            on_second = f"{CONNECTED}{device_id} to broker {two}"
            wait_for(lambda: device.lines(on_first), 20, what="connected to the first broker")
            device.wait_leds(lambda s: s == ".E..", "showing the first broker's E")
            assert device.lines(
                f"[serial] gridfleet: device {device_id} shows unit unit1, brokers {one}, {two}"
            )

            first.stop()
            wait_for(
                lambda: device.lines(on_second),
                20,
                what="connected to the second broker",
                context=lambda: "\n".join(device.lines("[serial]")),
            )
            device.wait_leds(lambda s: s == "...W", "showing the second broker's W")
            assert device.lines(f"{LOST} (broker {one}); trying broker {two}")
            # A session there: it says online, and what comes next shows.
            with MqttProbe(second.url) as probe:
                probe.subscribe(connection)
                probe.wait(connection, lambda m: m.payload == b"online")
                probe.publish(direction, "S", retain=True)
                device.wait_leds(lambda s: s == "..S.", "showing S from the second broker")
            assert not device.lines(CONNECT_FAILED)  # the second was tried at once, and took
        finally:
            device.close()
