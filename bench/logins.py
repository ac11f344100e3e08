"""`gridfleet bench logins`: how long STOP takes to reach every unit while strangers flood the
broker with wrong passwords.

A broker with accounts (its own `gridfleet broker` process, or `--broker URL --accounts FILE`),
`--units` unit accounts subscribed to the stop's latch, and an operator who engages the stop over
and over; between quiet phases and flood phases, another process sends `--flood` CONNECTs a
second with a wrong password for a real account name (`--name`, default `operator`, the name
README documents). Phases alternate quiet, flood, quiet, flood …; each reports the stop's
latency (operator's publish to the last unit's receipt) as median, p99 and max.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import multiprocessing
import re
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from multiprocessing.queues import Queue
from multiprocessing.synchronize import Event
from pathlib import Path

import numpy as np
import paho.mqtt.client as mqtt
from amqtt.mqtt.connect import ConnectPacket, ConnectPayload, ConnectVariableHeader
from paho.mqtt.enums import CallbackAPIVersion

from gridfleet.accounts import Accounts, default_accounts, load_accounts, write_accounts
from gridfleet.config import parse_broker_url, with_credentials
from gridfleet.errors import ConfigError
from gridfleet.protocol import Topics

ROOT = "bench-logins"
STOP_TIMEOUT_S = 60.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The benchmark's options."""
    parser.add_argument("--units", type=int, default=50, help="units listening (default 50)")
    parser.add_argument("--stops", type=int, default=20, help="stops per phase (default 20)")
    parser.add_argument("--flood", type=float, default=100.0, help="wrong logins a second (100)")
    parser.add_argument("--phases", type=int, default=2, help="quiet/flood pairs (default 2)")
    parser.add_argument("--name", default="operator", help="the account name the flood guesses")
    parser.add_argument("--broker", help="a running broker with accounts (default: its own)")
    parser.add_argument("--accounts", help="that broker's accounts file (with --broker)")
    parser.add_argument("--root", default=ROOT, help=f"topic root of those accounts ({ROOT})")
    parser.add_argument("--json", action="store_true", help="print JSON")


@dataclass
class Phase:
    """One phase's figures."""

    flood_per_s: float  # wrong logins sent a second (0: quiet)
    refused: int  # of them, answered with a refusal
    unanswered: int  # of them, not answered within 10 s
    stop_p50_ms: float
    stop_p99_ms: float
    stop_max_ms: float


def run(args: argparse.Namespace) -> int:
    """Run the phases; print a table or JSON."""
    if args.units < 1 or args.stops < 1 or args.phases < 1 or args.flood <= 0:
        print("--units, --stops, --phases and --flood must be positive", file=sys.stderr)
        return 2
    if (args.broker is None) != (args.accounts is None):
        print("--broker and --accounts go together", file=sys.stderr)
        return 2
    try:
        with _broker(args) as (url, accounts):
            phases = measure(url, accounts, Topics(args.root), args)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps([asdict(p) for p in phases]))
        return 0
    print("phase  wrong logins/s  refused  unanswered  stop p50 ms  p99 ms  max ms")
    for p in phases:
        name = "flood" if p.flood_per_s else "quiet"
        print(
            f"{name:5}  {p.flood_per_s:14.1f}  {p.refused:7}  {p.unanswered:10}  "
            f"{p.stop_p50_ms:11.1f}  {p.stop_p99_ms:6.1f}  {p.stop_max_ms:6.1f}"
        )
    return 0


@contextlib.contextmanager
def _broker(args: argparse.Namespace) -> Iterator[tuple[str, Accounts]]:
    """The broker's URL and accounts: the one given, or a `gridfleet broker` of our own."""
    if args.broker is not None:
        parse_broker_url(args.broker)
        yield args.broker, load_accounts(args.accounts)
        return
    accounts = default_accounts([f"u{i:03d}" for i in range(args.units)])
    with tempfile.TemporaryDirectory(prefix="gridfleet-bench-logins-") as tmp:
        path = Path(tmp) / "accounts.toml"
        write_accounts(accounts, path)
        command = [sys.executable, "-m", "gridfleet", "broker", "--port", "0", "--no-ws"]
        command += ["--accounts", str(path), "--root", args.root]
        errors = (Path(tmp) / "broker.log").open("w+")
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=errors, text=True)
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline()
            found = re.search(r"mqtt://[^ ]+", line)
            if found is None:
                errors.seek(0)
                said = errors.read().strip().splitlines()[-1:] or [line.strip() or "nothing"]
                raise ConfigError(f"the broker did not start: {said[0]}")
            yield found.group(0), accounts
        finally:
            proc.terminate()
            proc.wait(15)
            errors.close()


class _Unit:
    """A unit's account, subscribed to the latch; notes when each stop arrived."""

    def __init__(self, url: str, name: str, password: str, topic: str) -> None:
        broker = parse_broker_url(url)
        self.arrived: dict[bytes, float] = {}
        self.ready = threading.Event()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"{name}-bench")
        self.client.username_pw_set(name, password)
        self.client.on_connect = lambda c, u, f, rc, p: c.subscribe(topic, 1)
        self.client.on_subscribe = lambda c, u, mid, rcs, p: self.ready.set()
        self.client.on_message = self._arrived
        self.client.connect(broker.host, broker.port)
        self.client.loop_start()

    def _arrived(self, client: mqtt.Client, userdata: object, message: mqtt.MQTTMessage) -> None:
        self.arrived.setdefault(bytes(message.payload), time.monotonic())

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def measure(url: str, accounts: Accounts, topics: Topics, args: argparse.Namespace) -> list[Phase]:
    """Alternate quiet and flood phases; each engages the stop `args.stops` times."""
    latch = topics.fleet("estop")
    names = sorted(a.name for a in accounts.accounts.values() if a.role == "unit")[: args.units]
    units = [_Unit(url, n, accounts.get(n).password, latch) for n in names]
    operator = accounts.get("operator")
    boss = _Unit(url, operator.name, operator.password, latch)
    try:
        for unit in [*units, boss]:
            if not unit.ready.wait(30):
                raise ConfigError(f"a client could not log in to {parse_broker_url(url)}")
        phases = []
        for _ in range(args.phases):
            for flood in (0.0, args.flood):
                phases.append(_phase(url, units, boss, latch, flood, args))
        return phases
    finally:
        for unit in [*units, boss]:
            unit.close()


def _phase(
    url: str,
    units: list[_Unit],
    boss: _Unit,
    latch: str,
    flood: float,
    args: argparse.Namespace,
) -> Phase:
    counts: Queue[tuple[int, int, int]] = multiprocessing.Queue()
    done = multiprocessing.Event()
    flooder = None
    if flood:
        flooder = multiprocessing.Process(
            target=_flood, args=(url, args.name, flood, done, counts), daemon=True
        )
        flooder.start()
        time.sleep(1.0)  # pacing, not synchronisation: let the flood reach its rate first
    started = time.monotonic()
    latencies = []
    for k in range(args.stops):
        payload = f"engaged|operator|bench {uuid.uuid4().hex[:8]} {k}".encode()
        sent = time.monotonic()
        boss.client.publish(latch, payload, qos=1)
        deadline = sent + STOP_TIMEOUT_S
        while not all(payload in u.arrived for u in units) and time.monotonic() < deadline:
            time.sleep(0.001)  # polling the units' arrival times, with a deadline
        last = max(u.arrived.get(payload, deadline) for u in units)
        latencies.append((last - sent) * 1000)
        time.sleep(0.1)  # pacing between stops
    elapsed = time.monotonic() - started
    refused = unanswered = sent_total = 0
    if flooder is not None:
        done.set()
        sent_total, refused, unanswered = counts.get(timeout=30)
        flooder.join(30)
    return Phase(
        flood_per_s=round(sent_total / (elapsed + 1.0), 1) if flood else 0.0,
        refused=refused,
        unanswered=unanswered,
        stop_p50_ms=round(float(np.median(latencies)), 1),
        # The nearest value at or above the 99th percentile: a measured latency, not a blend.
        stop_p99_ms=round(float(np.percentile(latencies, 99, method="higher")), 1),
        stop_max_ms=round(max(latencies), 1),
    )


def _connect_packet(name: str, password: str) -> bytes:
    """An MQTT 3.1.1 CONNECT with a user name and password (clean session, keep-alive 10 s)."""
    header = ConnectVariableHeader(keep_alive=10)
    header.clean_session_flag = header.username_flag = header.password_flag = True
    client_id = f"{name}-flood-{uuid.uuid4().hex[:6]}"
    payload = ConnectPayload(client_id=client_id, username=name, password=password)
    return bytes(ConnectPacket(variable_header=header, payload=payload).to_bytes())


def _flood(
    url: str, name: str, per_s: float, done: Event, counts: Queue[tuple[int, int, int]]
) -> None:
    """Send `per_s` wrong-password CONNECTs a second until `done`; put (sent, refused, silent)."""
    broker = parse_broker_url(with_credentials(url, name, "not-the-password"))
    tally = [0, 0, 0]

    async def attempt() -> None:
        tally[0] += 1
        try:
            reader, writer = await asyncio.open_connection(broker.host, broker.port)
        except OSError:
            tally[2] += 1
            return
        try:
            writer.write(_connect_packet(name, "not-the-password"))
            answer = await asyncio.wait_for(reader.readexactly(4), 10)  # the CONNACK
            tally[1 if answer[3] != 0 else 2] += 1
        except (TimeoutError, OSError, asyncio.IncompleteReadError):
            tally[2] += 1
        finally:
            writer.close()

    async def main() -> None:
        tasks: set[asyncio.Task[None]] = set()
        began = time.monotonic()
        n = 0
        while not done.is_set():
            n += 1
            task = asyncio.create_task(attempt())
            tasks.add(task)
            task.add_done_callback(tasks.discard)
            await asyncio.sleep(max(0.0, began + n / per_s - time.monotonic()))
        if tasks:
            await asyncio.wait(tasks, timeout=15)

    asyncio.run(main())
    counts.put((tally[0], tally[1], tally[2]))
