"""`gridfleet bench logins`: how long STOP takes to reach every unit, and whether each role can
still log in, while strangers flood the broker with wrong passwords from another address.

A broker with accounts (its own `gridfleet broker` process, from this checkout and from each
`--tree`, or `--broker URL --accounts FILE`), `--units` unit accounts subscribed to the stop's
latch, and an operator who engages the stop over and over; between quiet phases and flood phases,
another process sends `--flood` CONNECTs a second from `--from` with a wrong password for real
account names (`--name`/`--names`, default the five probed below). Throughout every phase a third
process logs in with the right password from 127.0.0.1 as `operator`, `coordinator`, `dashboard`,
a unit and its device, `--logins-per-s` times a second each. Phases alternate quiet, flood, quiet,
flood …; each reports the stop's latency (operator's publish to the last unit's receipt) as
median, p99 and max, and each role's logins let in, tried and the slowest answer.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import ipaddress
import json
import multiprocessing
import statistics
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import asdict, dataclass, field
from multiprocessing.queues import Queue
from multiprocessing.synchronize import Event
from pathlib import Path

import numpy as np
import paho.mqtt.client as mqtt
from amqtt.mqtt.connect import ConnectPacket, ConnectPayload, ConnectVariableHeader
from paho.mqtt.enums import CallbackAPIVersion

from gridfleet.accounts import Accounts, default_accounts, load_accounts, write_accounts
from gridfleet.bench.flood_tree import BROKER_READY, Component, Tree, this_checkout, wheel_tree
from gridfleet.config import parse_broker_url
from gridfleet.errors import ConfigError
from gridfleet.protocol import Topics

ROOT = "bench-logins"
STOP_TIMEOUT_S = 60.0
ANSWER_S = 10.0  # a CONNECT not answered within this counts as unanswered (a failed login)
ROLES = ("operator", "coordinator", "dashboard", "unit", "device")
PROBE_FROM = "127.0.0.1"  # where the right-password logins come from: not the flood's address
DISCONNECT = b"\xe0\x00"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The benchmark's options."""
    parser.add_argument("--units", type=int, default=50, help="units listening (default 50)")
    parser.add_argument("--stops", type=int, default=20, help="stops per phase (default 20)")
    parser.add_argument("--flood", type=float, default=100.0, help="wrong logins a second (100)")
    parser.add_argument("--phases", type=int, default=2, help="quiet/flood pairs (default 2)")
    parser.add_argument(
        "--seconds", type=float, default=10.0, help="each phase at least, s; the stops spread (10)"
    )
    parser.add_argument(
        "--name",
        action="append",
        default=[],
        help="an account name the flood guesses (repeatable; default: the five probed)",
    )
    parser.add_argument("--names", help="the same, comma-separated: operator,coordinator,…")
    parser.add_argument(
        "--from",
        dest="sources",
        action="append",
        default=[],
        metavar="ADDR",
        help="the flood's source address, 127.x (repeatable or comma-separated; 127.0.0.2)",
    )
    parser.add_argument(
        "--logins-per-s", type=float, default=2.0, help="each role's right logins a second (2)"
    )
    parser.add_argument(
        "--tree",
        action="append",
        default=[],
        metavar="DIR",
        help="also run the broker from a wheel of this checkout (repeatable), alternating with "
        "this one: DIR first, then this checkout, --repeat times",
    )
    parser.add_argument("--repeat", type=int, default=1, help="runs of each tree (default 1)")
    parser.add_argument(
        "--broker", help="a running broker with accounts, one URL (default: its own)"
    )
    parser.add_argument("--accounts", help="that broker's accounts file (with --broker)")
    parser.add_argument("--root", default=ROOT, help=f"topic root of those accounts ({ROOT})")
    parser.add_argument("--json", action="store_true", help="print JSON (every phase of every run)")


@dataclass
class Logins:
    """One role's right-password logins in a phase."""

    account: str
    ok: int  # let in (CONNACK 0)
    tried: int
    slowest_ms: float  # the slowest answer (ANSWER_S when one never came)


@dataclass
class Phase:
    """One phase's figures."""

    flood_per_s: float  # wrong logins sent a second (0: quiet)
    refused: int  # of them, answered with a refusal
    unanswered: int  # of them, not answered within 10 s
    stop_p50_ms: float
    stop_p99_ms: float
    stop_max_ms: float
    tree: str = ""
    run: int = 0
    kind: str = "quiet"
    logins: dict[str, Logins] = field(default_factory=dict)  # by role


def _mistake(args: argparse.Namespace) -> str | None:
    """The options' mistake in one line, or None."""
    if args.units < 1 or args.stops < 1 or args.phases < 1 or args.flood <= 0:
        return "--units, --stops, --phases and --flood must be positive"
    if args.seconds <= 0 or args.repeat < 1 or args.logins_per_s < 0:
        return "--seconds and --repeat must be positive, --logins-per-s not negative"
    if (args.broker is None) != (args.accounts is None):
        return "--broker and --accounts go together"
    if args.broker is not None and args.tree:
        return "--tree starts brokers of its own: not with --broker"
    for source in args.sources:
        try:
            loopback = ipaddress.ip_address(source).version == 4
            loopback = loopback and ipaddress.ip_address(source).is_loopback
        except ValueError:
            loopback = False
        if not loopback:
            return f"--from {source}: not a loopback IPv4 address (127.x.y.z)"
    return None


def _split(values: list[str]) -> list[str]:
    """Repeated and comma-separated values, in order, each once."""
    found = [v.strip() for value in values for v in value.split(",") if v.strip()]
    return list(dict.fromkeys(found))


def run(args: argparse.Namespace) -> int:
    """Run the phases (each tree `--repeat` times, alternating); print a table or JSON."""
    args.sources = _split(args.sources) or ["127.0.0.2"]
    args.name = _split([*args.name, *([args.names] if args.names else [])])
    mistake = _mistake(args)
    if mistake is not None:
        print(mistake, file=sys.stderr)
        return 2
    phases: list[Phase] = []
    try:
        with tempfile.TemporaryDirectory(prefix="gridfleet-bench-logins-") as tmp:
            work = Path(tmp)
            if args.broker is not None:
                parse_broker_url(args.broker)
                accounts = load_accounts(args.accounts)
                phases = measure(args.broker, accounts, Topics(args.root), args, "--broker", 0)
            else:
                phases = _own_runs(args, work)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    if args.json:
        print(json.dumps([asdict(p) for p in phases]))
    else:
        print_table(phases)
    return 0


def _own_runs(args: argparse.Namespace, work: Path) -> list[Phase]:
    """Brokers of our own, one a run: each `--tree`, then this checkout, `--repeat` times."""
    trees: list[Tree] = [wheel_tree(d, work) for d in args.tree] + [this_checkout(work)]
    for tree in trees:
        print(f"bench logins: {tree.label} imports {tree.imports}", file=sys.stderr)
    # One unit more than listen: the probed unit logs in and out beside them, never displacing.
    accounts = default_accounts([f"u{i:03d}" for i in range(args.units + 1)])
    path = work / "accounts.toml"
    write_accounts(accounts, path)
    phases: list[Phase] = []
    for k in range(args.repeat):
        for tree in trees:
            here = work / f"run-{len(phases)}"
            here.mkdir()
            with _broker(tree, path, args.root, here) as url:
                phases += measure(url, accounts, Topics(args.root), args, tree.label, k)
    return phases


@contextlib.contextmanager
def _broker(tree: Tree, accounts: Path, root: str, work: Path) -> Iterator[str]:
    """A `gridfleet broker` of `tree`'s, its URL while it runs."""
    argv = ["broker", "--port", "0", "--no-ws", "--accounts", str(accounts), "--root", root]
    broker = Component("broker", argv, tree, work)
    try:
        line = broker.first_line()
        found = BROKER_READY.search(line)
        if found is None:
            broker.check()
            raise ConfigError(f"the broker did not start: {line.strip() or broker.last_words()}")
        yield found.group(1)
    finally:
        broker.stop()


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


def probed(accounts: Accounts, listening: list[str]) -> dict[str, tuple[str, str]]:
    """The account logged in as for each role (name, password): a unit not listening if any."""
    by_role: dict[str, tuple[str, str]] = {}
    for role in ("operator", "coordinator", "dashboard"):
        if role in accounts.accounts:
            by_role[role] = (role, accounts.get(role).password)
    units = sorted(a.name for a in accounts.accounts.values() if a.role == "unit")
    spare = [u for u in units if u not in listening] or units
    if spare:
        by_role["unit"] = (spare[-1], accounts.get(spare[-1]).password)
        device = f"device-{spare[-1]}"
        if device in accounts.accounts:
            by_role["device"] = (device, accounts.get(device).password)
    return by_role


def measure(
    url: str,
    accounts: Accounts,
    topics: Topics,
    args: argparse.Namespace,
    label: str = "",
    run: int = 0,
) -> list[Phase]:
    """Alternate quiet and flood phases; each engages the stop `args.stops` times."""
    latch = topics.fleet("estop")
    names = sorted(a.name for a in accounts.accounts.values() if a.role == "unit")[: args.units]
    roles = probed(accounts, names)
    guessed = args.name or [name for name, _ in roles.values()]
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
                phase = _phase(url, units, boss, latch, flood, guessed, roles, args)
                phase.tree, phase.run = label, run
                print(f"bench logins: {label} run {run}: {_line(phase)}", file=sys.stderr)
                phases.append(phase)
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
    guessed: list[str],
    roles: dict[str, tuple[str, str]],
    args: argparse.Namespace,
) -> Phase:
    counts: Queue[tuple[int, int, int]] = multiprocessing.Queue()
    tallies: Queue[dict[str, tuple[int, int, float]]] = multiprocessing.Queue()
    done = multiprocessing.Event()
    flooder = prober = None
    if flood:
        flooder = multiprocessing.Process(
            target=_flood,
            args=(url, guessed, args.sources, flood, done, counts),
            daemon=True,
        )
        flooder.start()
        time.sleep(1.0)  # pacing, not synchronisation: let the flood reach its rate first
    if args.logins_per_s > 0 and roles:
        prober = multiprocessing.Process(
            target=_probe, args=(url, roles, args.logins_per_s, done, tallies), daemon=True
        )
        prober.start()
    started = time.monotonic()
    latencies = []
    for k in range(args.stops):
        # The stops spread over the phase (at least 0.1 s apart), while the logins go on.
        time.sleep(max(0.0, started + k * args.seconds / args.stops - time.monotonic()))
        payload = f"engaged|operator|bench {uuid.uuid4().hex[:8]} {k}".encode()
        sent = time.monotonic()
        boss.client.publish(latch, payload, qos=1)
        deadline = sent + STOP_TIMEOUT_S
        while not all(payload in u.arrived for u in units) and time.monotonic() < deadline:
            time.sleep(0.001)  # polling the units' arrival times, with a deadline
        last = max(u.arrived.get(payload, deadline) for u in units)
        latencies.append((last - sent) * 1000)
        time.sleep(0.1)  # pacing between stops
    time.sleep(max(0.0, started + args.seconds - time.monotonic()))  # pacing: the phase's length
    elapsed = time.monotonic() - started
    done.set()
    refused = unanswered = sent_total = 0
    if flooder is not None:
        sent_total, refused, unanswered = counts.get(timeout=30)
        flooder.join(30)
    logins: dict[str, Logins] = {}
    if prober is not None:
        tally = tallies.get(timeout=30)
        prober.join(30)
        for role in ROLES:
            if role in tally:
                ok, tried, slowest = tally[role]
                logins[role] = Logins(roles[role][0], ok, tried, round(slowest, 1))
    return Phase(
        flood_per_s=round(sent_total / (elapsed + 1.0), 1) if flood else 0.0,
        refused=refused,
        unanswered=unanswered,
        stop_p50_ms=round(float(np.median(latencies)), 1),
        # The nearest value at or above the 99th percentile: a measured latency, not a blend.
        stop_p99_ms=round(float(np.percentile(latencies, 99, method="higher")), 1),
        stop_max_ms=round(max(latencies), 1),
        kind="flood" if flood else "quiet",
        logins=logins,
    )


def _connect_packet(name: str, password: str, what: str = "flood") -> bytes:
    """An MQTT 3.1.1 CONNECT with a user name and password (clean session, keep-alive 10 s)."""
    header = ConnectVariableHeader(keep_alive=10)
    header.clean_session_flag = header.username_flag = header.password_flag = True
    client_id = f"{name}-{what}-{uuid.uuid4().hex[:6]}"
    payload = ConnectPayload(client_id=client_id, username=name, password=password)
    return bytes(ConnectPacket(variable_header=header, payload=payload).to_bytes())


async def _login(
    host: str, port: int, source: str, name: str, password: str, what: str
) -> bool | None:
    """One CONNECT from `source`: True let in, False refused, None no answer (then closed)."""
    try:
        reader, writer = await asyncio.open_connection(host, port, local_addr=(source, 0))
    except OSError:
        return None
    try:
        writer.write(_connect_packet(name, password, what))
        answer = await asyncio.wait_for(reader.readexactly(4), ANSWER_S)  # the CONNACK
        if answer[3] == 0:
            writer.write(DISCONNECT)
            await writer.drain()
            return True
        return False
    except (TimeoutError, OSError, asyncio.IncompleteReadError):
        return None
    finally:
        writer.close()


Attempt = Callable[[int], Awaitable[None]]


async def _paced(per_s: float, offset_s: float, done: Event, attempt: Attempt) -> None:
    """Start `attempt(n)` `per_s` times a second (the first after `offset_s`) until `done`;
    then wait for those still under way."""
    tasks: set[asyncio.Task[None]] = set()
    began = time.monotonic() + offset_s
    n = 0
    while True:
        await asyncio.sleep(max(0.0, began + n / per_s - time.monotonic()))
        if done.is_set():
            break
        task: asyncio.Task[None] = asyncio.ensure_future(attempt(n))
        tasks.add(task)
        task.add_done_callback(tasks.discard)
        n += 1
    if tasks:
        await asyncio.wait(tasks, timeout=ANSWER_S + 5)


def _flood(
    url: str,
    names: list[str],
    sources: list[str],
    per_s: float,
    done: Event,
    counts: Queue[tuple[int, int, int]],
) -> None:
    """Send `per_s` wrong-password CONNECTs a second, every name from every source in turn,
    until `done`; put (sent, refused, silent)."""
    broker = parse_broker_url(url)
    pairs = [(source, name) for source in sources for name in names]
    tally = [0, 0, 0]

    async def attempt(n: int) -> None:
        tally[0] += 1
        source, name = pairs[n % len(pairs)]
        said = await _login(broker.host, broker.port, source, name, "not-the-password", "flood")
        if said is not True:  # a wrong password let in would be counted as neither
            tally[1 if said is False else 2] += 1

    asyncio.run(_paced(per_s, 0.0, done, attempt))
    counts.put((tally[0], tally[1], tally[2]))


def _probe(
    url: str,
    roles: dict[str, tuple[str, str]],
    per_s: float,
    done: Event,
    out: Queue[dict[str, tuple[int, int, float]]],
) -> None:
    """Log in with the right password as each role `per_s` times a second from PROBE_FROM
    (CONNECT, CONNACK, DISCONNECT) until `done`; put {role: (let in, tried, slowest ms)}."""
    broker = parse_broker_url(url)
    tally = {role: [0, 0, 0.0] for role in roles}

    def attempt_as(role: str) -> Attempt:
        name, password = roles[role]

        async def attempt(n: int) -> None:
            began = time.monotonic()
            said = await _login(broker.host, broker.port, PROBE_FROM, name, password, "probe")
            took = ANSWER_S * 1000 if said is None else (time.monotonic() - began) * 1000
            counted = tally[role]
            counted[0] += 1 if said else 0
            counted[1] += 1
            counted[2] = max(counted[2], took)

        return attempt

    async def main() -> None:
        gap = 1.0 / per_s / len(roles)  # the roles' logins staggered over each period
        await asyncio.gather(
            *(_paced(per_s, i * gap, done, attempt_as(role)) for i, role in enumerate(roles))
        )

    asyncio.run(main())
    out.put({role: (int(t[0]), int(t[1]), float(t[2])) for role, t in tally.items()})


def _cell(logins: Logins | None) -> str:
    """`ok/tried (slowest ms)`, or a dash."""
    if logins is None:
        return "-"
    return f"{logins.ok}/{logins.tried} ({logins.slowest_ms:.0f})"


def _line(p: Phase) -> str:
    """One phase in words, for the progress on stderr."""
    logins = ", ".join(f"{role} {_cell(p.logins.get(role))}" for role in p.logins)
    return (
        f"{p.kind} {p.flood_per_s:g}/s refused {p.refused} unanswered {p.unanswered}; stop p50 "
        f"{p.stop_p50_ms} p99 {p.stop_p99_ms} max {p.stop_max_ms} ms; logins {logins or 'none'}"
    )


def summarise(phases: list[Phase]) -> list[Phase]:
    """Per tree and per phase of a run: the medians of the runs' figures; logins summed over
    the runs, the slowest of them."""
    groups: dict[tuple[str, int], list[Phase]] = {}
    counters: dict[tuple[str, int], int] = {}
    for p in phases:
        k = counters.get((p.tree, p.run), 0)
        counters[(p.tree, p.run)] = k + 1
        groups.setdefault((p.tree, k), []).append(p)
    summary = []
    for (tree, _), group in groups.items():

        def med(attr: str, group: list[Phase] = group) -> float:
            return round(float(statistics.median(getattr(p, attr) for p in group)), 1)

        logins = {}
        for role in ROLES:
            each = [p.logins[role] for p in group if role in p.logins]
            if each:
                logins[role] = Logins(
                    each[0].account,
                    sum(x.ok for x in each),
                    sum(x.tried for x in each),
                    max(x.slowest_ms for x in each),
                )
        summary.append(
            Phase(
                flood_per_s=med("flood_per_s"),
                refused=int(med("refused")),
                unanswered=int(med("unanswered")),
                stop_p50_ms=med("stop_p50_ms"),
                stop_p99_ms=med("stop_p99_ms"),
                stop_max_ms=med("stop_max_ms"),
                tree=tree,
                run=len(group),
                kind=group[0].kind,
                logins=logins,
            )
        )
    return summary


def print_table(phases: list[Phase]) -> None:
    """The summary as a table: one row per tree and phase (medians over `runs`); each role's
    logins as let in/tried (the slowest answer, ms), summed over the runs."""
    rows = summarise(phases)
    width = max(len("tree"), *(len(p.tree) for p in rows))
    roles = [r for r in ROLES if any(r in p.logins for p in rows)]
    head = f"{'tree':{width}}  runs  phase  wrong/s  refused  unanswered  stop p50  p99 ms  max ms"
    print(head + "".join(f"  {r:>14}" for r in roles))
    for p in rows:
        cells = "".join(f"  {_cell(p.logins.get(r)):>14}" for r in roles)
        print(
            f"{p.tree:{width}}  {p.run:4}  {p.kind:5}  {p.flood_per_s:7.1f}  {p.refused:7}  "
            f"{p.unanswered:10}  {p.stop_p50_ms:8.1f}  {p.stop_p99_ms:6.1f}  "
            f"{p.stop_max_ms:6.1f}{cells}"
        )
