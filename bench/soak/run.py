"""The chaos soak: the real system in separate processes, faults injected while jobs flow, and
the checks of `bench.soak.check` over what was recorded.

Two lanes of faults: the main lane kills (SIGKILL or SIGTERM) and restarts the units process,
the coordinator and the embedded broker, pauses processes (SIGSTOP/SIGCONT) past the staleness
timeout, and cuts or slows every client's connection through `FaultyProxy`; one fault at a time,
each followed by its recovery. The stop lane engages the stop from an operator (the latch) or a
device (a press) and releases it as an operator; it engages only between main-lane faults (a unit
cannot obey a stop it cannot read), and main-lane faults then strike while the stop is held.

`Soak` is one run, whatever its topology; where its parts run (all on loopback, on hosts of a LAN,
or with a hall's bridged broker) is one of the three classes of `bench.soak.topologies`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import random
import shutil
import signal
import statistics
import time
import uuid
from collections import Counter, defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any, TextIO

import aiomqtt

from gridfleet.accounts import Accounts
from gridfleet.bench.lan import Host
from gridfleet.bench.soak.check import (
    FINAL,
    Disturbed,
    Event,
    JobSeen,
    Released,
    SoakLimits,
    SoakVerdict,
    Stop,
    Truth,
    check,
)
from gridfleet.bench.soak.faults import (
    CLUSTER_FAMILIES,
    LOCAL_FAMILIES,
    NETWORK_FAMILIES,
    NETWORK_HOSTS,
    WILL_SLACK_S,
    Fault,
    main_faults,
    stop_faults,
)
from gridfleet.bench.soak.listen import SoakListener
from gridfleet.bench.soak.proxy import FaultyProxy
from gridfleet.bench.soak.scenario import make_soak_scenario
from gridfleet.bus import connect_first
from gridfleet.config import parse_broker_url
from gridfleet.console.operator import operator_session
from gridfleet.ports import free_port
from gridfleet.protocol import JobHistoryPage, Topics
from gridfleet.system.assembly import SystemSpec, cli, start_broker_process
from gridfleet.system.supervisor import Child, ChildSpec, Supervisor

RECOVERY_WAIT_S = 60.0  # a fault not recovered from within this is reported
DEVICE = "soak-dev"
STALL_S = 90.0  # no progress (start-up done, a fault injected) this long: say where it waits
MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
MOSQUITTO_SUB = shutil.which("mosquitto_sub") or "/usr/bin/mosquitto_sub"
HALL = "hall1"  # the hall broker's bridge account
EXIT_WAIT_S = 15.0  # a process signalled to stop that is still running after this is a finding
RELEASE_AGAIN_S = 5.0  # an operator whose release did not take releases again after this


@dataclass(frozen=True)
class SoakConfig:
    """What to soak and for how long."""

    minutes: float
    units: int = 12
    seed: int = 0
    broker: str | None = None  # None: an embedded broker the soak restarts too
    step_s: float = 0.1
    faults: tuple[str, ...] = LOCAL_FAMILIES
    drain_s: float = 90.0  # after the faults: time for every job to end
    stranded_s: float = 30.0
    # The units and the coordinator on hosts of a LAN of namespaces (root), the broker on this
    # machine's LAN address with accounts; the silent and stall faults need it.
    network: bool = False
    # With `network`: the units on a hall's Mosquitto bridged to a central Mosquitto (no broker
    # restarts: Mosquitto keeps the latch only as often as it saves).
    bridge: bool = False
    # A broker cluster the soak starts ("aedes", "rabbitmq"; bench.soak.cluster), whose nodes it
    # kills, pauses and cuts off; None: one broker.
    cluster: str | None = None
    # Seconds between two main-lane faults, and between two stops (drawn at random in each).
    fault_gap_s: tuple[float, float] = (0.1, 0.5)
    stop_gap_s: tuple[float, float] = (1.0, 4.0)
    keep_active: int | None = None  # jobs the feed keeps active (None: half as many as units)


@dataclass
class SoakResult:
    """The figures and what the checks found."""

    minutes: float
    units: int
    faults: Counter[str]
    verdict: SoakVerdict
    recoveries_s: list[float] = field(default_factory=list)  # after each broker restart
    unrecovered: list[str] = field(default_factory=list)  # faults the system did not recover from
    release_repeats: int = 0  # operator releases that had to be given again (not a failure)
    fault_s: dict[str, list[float]] = field(default_factory=dict)  # main-lane fault to flowing
    # --network: a host's link cut for longer than the keep-alive, to its will seen (`broken`)
    detections_s: list[float] = field(default_factory=list)
    # --cluster: per node fault's kind, from the fault to the fleet moving again (seconds)
    node_recoveries_s: dict[str, list[float]] = field(default_factory=dict)
    cluster: str | None = None
    extra: dict[str, object] = field(default_factory=dict)  # the topology's own figures
    job_ends_from_history: int = 0  # jobs whose end only the coordinator's history told

    @property
    def ok(self) -> bool:
        """Every check passed and every fault was recovered from."""
        return self.verdict.ok and not self.unrecovered

    def as_json(self) -> dict[str, Any]:
        """The JSON `gridfleet bench soak --json` prints."""
        v = self.verdict
        return {
            "minutes": self.minutes,
            "units": self.units,
            "faults": dict(sorted(self.faults.items())),
            "collisions": v.collisions,
            "moved_while_stopped": v.moved_while_stopped,
            "moved_before_the_hall_had_the_stop": v.moved_before_the_hall_had_it,
            "worst_stop_to_hall_s": (
                None if v.worst_stop_to_hall_s is None else round(v.worst_stop_to_hall_s, 2)
            ),
            "jobs_submitted": v.jobs_submitted,
            "jobs_done": v.jobs_done,
            "jobs_lost": v.jobs_lost,
            "jobs_duplicated": v.jobs_duplicated,
            "units_stranded": v.units_stranded,
            "faults_unrecovered": len(self.unrecovered),
            "release_repeats": self.release_repeats,
            "job_ends_from_history": self.job_ends_from_history,
            "max_recovery_s": round(max(self.recoveries_s), 3) if self.recoveries_s else None,
            "max_fault_s": {
                kind: round(max(took), 2) for kind, took in sorted(self.fault_s.items())
            },
            "max_silent_detection_s": (
                round(max(self.detections_s), 2) if self.detections_s else None
            ),
            "median_fault_s": {
                kind: round(statistics.median(took), 2)
                for kind, took in sorted(self.fault_s.items())
            },
            "cluster": self.cluster,
            "node_recovery_s": {
                kind: spread(took) for kind, took in sorted(self.node_recoveries_s.items())
            },
            **self.extra,
            "ok": self.ok,
            "details": v.details + self.unrecovered,
        }


def spread(seconds: list[float]) -> dict[str, float | int]:
    """How many, median, p99 (nearest rank: the worst of fewer than 100) and worst, in s."""
    ordered = sorted(seconds)
    rank = max(0, -(-99 * len(ordered) // 100) - 1)  # nearest-rank p99, as an index
    return {
        "n": len(ordered),
        "median": round(statistics.median(ordered), 2),
        "p99": round(ordered[rank], 2),
        "max": round(ordered[-1], 2),
    }


def hall_stops(path: Path, topics: Topics) -> list[Stop]:
    """The stop as the hall's broker had it, from its watcher's lines (see `_start_hall`)."""
    if not path.exists():
        return []
    watch = SoakListener("", topics, "hall-watch")
    watch.settling = False
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        at, _, rest = line.partition(" ")
        topic, _, payload = rest.partition(" ")
        with contextlib.suppress(ValueError):
            watch.take(topic, payload.encode(), float(at))
    return [Stop(e.t, e.engaged, "hall") for e in watch.events if isinstance(e, Stop)]


def read_truth(path: Path) -> Iterator[Truth]:
    """The truth lines a units process wrote (a line cut short by SIGKILL is skipped)."""
    if not path.exists():
        return
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            d = json.loads(line)
        except ValueError:
            continue
        positions = {u: (p[0], p[1]) for u, p in d["positions"].items()}
        yield Truth(d["t"], d["pid"], d["collisions"], positions)


class Soak:
    """One soak run in a temporary directory; `run()` returns its result.

    The base of the three topologies (`bench.soak.topologies`): the hooks below say where the
    broker and the processes run and how the soak logs in; the base is every client on loopback.
    """

    # The hosts the network faults strike, and how late a will may come (a broker's keep-alive).
    FAULT_HOSTS: tuple[str, ...] = NETWORK_HOSTS
    WILL_SLACK: tuple[float, float] = WILL_SLACK_S
    NETWORK_FAULTS = False  # whether the network's faults (cut, stall, narrow a host) can strike
    RESTARTS_BROKER = True  # whether the broker faults restart an embedded broker
    CLUSTER_FAULTS = False  # whether the node faults (a cluster's node killed, paused, cut) can
    LIVE_ONLY = False  # whether the listener ignores retained replays (a cluster's nodes differ)

    def __init__(self, cfg: SoakConfig, workdir: Path, log: TextIO) -> None:
        self.cfg = cfg
        self.dir = workdir
        self.log = log
        self.rng = random.Random(cfg.seed)
        self.root = f"soak-{uuid.uuid4().hex[:8]}"
        self.topics = Topics(self.root)
        self.scenario = make_soak_scenario(cfg.units, cfg.seed, workdir)
        self.unit_ids = [u.id for u in self.scenario.units]
        self.sup = Supervisor(out=log, restart_delay=0.3, max_restart_delay=2.0, stable_after=3.0)
        self.children: dict[str, Child] = {}
        self.faults: Counter[str] = Counter()
        self.fault_times: list[tuple[float, float, str]] = []  # (start, flowing again, kind)
        self.progress = 0  # start-up done, or a fault injected: what the watchdog watches
        self.stalled = False  # set by the watchdog when it gave up on the run
        self.recoveries: list[float] = []
        self.release_repeats = 0
        self.ends_from_history = 0  # jobs whose end only the coordinator's history told
        self.unrecovered: list[str] = []
        self.recorded: list[Event] = []  # the soak's own events: disturbances and releases
        self.tasks: list[asyncio.Task[None]] = []
        self.calm = asyncio.Lock()  # held by a main-lane fault, and while a stop is engaged
        self.broker_url = ""
        self.proxy: FaultyProxy | None = None
        self.proxies: list[FaultyProxy] = []  # every proxy: the cut and delay faults strike all
        self.listener: SoakListener | None = None
        self.truth = workdir / "truth.jsonl"
        self.listen = "127.0.0.1"  # where the soak's broker and proxy listen
        self.hosts: dict[str, Host] = {}  # the LAN's hosts, by name, where there is a LAN
        self.detections: list[float] = []
        self.accounts = Accounts({})
        self.operator_url = ""  # how the soak's operator and its device log in
        self.device_url = ""

    # ---- the system ---------------------------------------------------------------------

    async def start(self) -> None:
        """Broker (ours, on a fixed port), proxy, coordinator, units, feed and the listener."""
        cfg = self.cfg
        logins = self._open()
        self.broker_url = await self._start_broker(logins)
        self.operator_url = self._login("operator")
        self.device_url = self._login(DEVICE)
        urls = await self._links()
        self.listener = SoakListener(
            self._listener_url(), self.topics, self._client_id("listener"), self.LIVE_ONLY
        )
        self.tasks.append(asyncio.create_task(self.listener.run()))
        common = ["--root", self.root, "--step", str(cfg.step_s), *logins]
        scenario = str(self.scenario.path)
        coordinator = cli("coordinator", "--broker", urls["coordinator"], *common)
        coordinator += ["--map", str(self.scenario.map_path), "--db", str(self.dir / "jobs.db")]
        robots = cli("robots", "--broker", urls["robots"], *common, "--scenario", scenario)
        robots += ["--state", str(self.dir / "units.sqlite3"), "--truth", str(self.truth)]
        coordinator, robots = self._place(coordinator, robots)
        keep = str(cfg.keep_active or max(2, cfg.units // 2))
        feed = cli("feed", "--broker", urls["operator"], *common, "--scenario", scenario)
        feed += ["--demo", "--keep-active", keep]
        for name, argv in (("coordinator", coordinator), ("robots", robots), ("operator", feed)):
            self.children[name] = await self.sup.start(ChildSpec(name, argv))
        await self._wait_flowing(time.time(), "start-up")
        self.progress += 1

    # ---- the topology's hooks -----------------------------------------------------------

    async def _links(self) -> dict[str, str]:
        """The proxy (or proxies) the components reach the broker through; each component's
        broker URL (`robots`, `coordinator`, `operator`: the feed)."""
        target = parse_broker_url(self.broker_url)
        self.proxy = FaultyProxy(target.host, target.port, listen=self.listen)
        self.proxies = [self.proxy]
        via = await self._units_broker(await self.proxy.start())
        direct = self._coordinator_broker(via)
        return {"robots": via, "coordinator": direct, "operator": direct}

    def _listener_url(self) -> str:
        """Where the soak's listener listens: straight on the broker, as the operator."""
        return self.operator_url

    def _open(self) -> list[str]:
        """Make what the topology needs before its broker; the flags that log each component in."""
        return []

    async def _start_broker(self, logins: list[str]) -> str:
        """The embedded broker (one the soak restarts), or the one given; its URL."""
        if self.cfg.broker is not None:
            return self.cfg.broker
        spec = SystemSpec(
            self.scenario, root=self.root, mqtt_port=free_port(), ws_port=None, listen=self.listen
        )
        url, _ = await start_broker_process(self.sup, spec, logins)
        self.children["broker"] = self.sup.children[-1]
        return url

    async def _units_broker(self, proxy_port: int) -> str:
        """The URL the units reach their broker at: through the proxy (delays, cuts)."""
        return f"mqtt://{self.listen}:{proxy_port}"

    def _coordinator_broker(self, via: str) -> str:
        """The URL the coordinator and the feed reach the broker at: on loopback, the units'."""
        return via

    def _place(self, coordinator: list[str], robots: list[str]) -> tuple[list[str], list[str]]:
        """The coordinator's and the units' commands, run where the topology puts them."""
        return coordinator, robots

    def _login(self, account: str) -> str:
        """The broker's URL for the soak's `account` (operator, device): on loopback, no login."""
        return self.broker_url

    def _client_id(self, what: str, device: bool = False) -> str:
        """A client id of the soak's own."""
        return f"{self.root}-{what}"

    def _hall_stops(self) -> list[Stop]:
        """The stop as a hall's broker had it, where there is one."""
        return []

    def _close(self) -> None:
        """Remove what `_open` made."""

    async def _wait_flowing(self, since: float, what: str) -> float | None:
        """Wait until every unit's state and the coordinator's routes arrived after `since`;
        the time that took, or None (and reported) after RECOVERY_WAIT_S."""
        listener = self.listener
        assert listener is not None
        deadline = time.monotonic() + RECOVERY_WAIT_S
        while time.monotonic() < deadline:
            late = [u for u in self.unit_ids if listener.last_state.get(u, 0.0) <= since]
            if not late and listener.last_routes > since:
                return time.time() - since
            await asyncio.sleep(0.05)  # polling the listener, with a deadline
        late = [u for u in self.unit_ids if listener.last_state.get(u, 0.0) <= since]
        self.unrecovered.append(
            f"{what}: after {RECOVERY_WAIT_S:.0f} s, no state from {', '.join(late) or 'none'}"
            + ("" if listener.last_routes > since else " and no routes from the coordinator")
        )
        return None

    # ---- the main lane ------------------------------------------------------------------

    async def main_lane(self, deadline: float) -> None:
        """One process or link fault at a time, each with its recovery, until `deadline`."""
        cfg = self.cfg
        restartable = cfg.broker is None and self.RESTARTS_BROKER
        families = [
            f
            for f in cfg.faults
            if (f != "broker" or restartable)
            and (self.NETWORK_FAULTS or f not in NETWORK_FAMILIES)
            and (self.CLUSTER_FAULTS or f not in CLUSTER_FAMILIES)
        ]
        hosts, slack = self.FAULT_HOSTS, self.WILL_SLACK
        for fault in main_faults(self.rng, families, self.cfg.step_s, hosts, slack):
            await asyncio.sleep(self.rng.uniform(*cfg.fault_gap_s))  # the schedule's pacing
            if time.monotonic() >= deadline:
                return
            async with self.calm:
                start = time.time()
                self.faults[fault.kind] += 1
                self.progress += 1
                await self._apply(fault)
                # Disturbed from the fault until everything flows again (or the wait gave up).
                await self._wait_flowing(time.time(), f"{fault.kind} at {start:.2f}")
                flowing = time.time()
                self.recorded.append(Disturbed(start, flowing))
                self.fault_times.append((start, flowing, fault.kind))

    async def _apply(self, fault: Fault) -> None:
        if fault.kind.startswith(("kill_", "term_")):
            await self._restart(
                fault.target, signal.SIGKILL if "kill" in fault.kind else signal.SIGTERM
            )
        elif fault.kind.startswith("pause_"):
            process = self.children[fault.target].process
            assert process is not None
            process.send_signal(signal.SIGSTOP)
            try:
                await asyncio.sleep(fault.hold_s)  # the fault itself: paused this long
            finally:
                process.send_signal(signal.SIGCONT)
        elif fault.kind == "cut":
            for proxy in self.proxies:
                proxy.refusing = True
                proxy.cut()
            try:
                await asyncio.sleep(fault.hold_s)  # the fault itself: the link stays down
            finally:
                for proxy in self.proxies:
                    proxy.refusing = False
        elif fault.kind == "delay":
            for proxy in self.proxies:
                proxy.latency_s = fault.latency_s
            try:
                await asyncio.sleep(fault.hold_s)  # the fault itself: a slow link for a while
            finally:
                for proxy in self.proxies:
                    proxy.latency_s = 0.0
        elif fault.kind.startswith(("silent_", "stall_", "narrow_")):
            host = self.hosts[fault.target]
            since = time.time()
            if fault.kind.startswith("narrow_"):
                host.narrow(fault.kbit)
            else:
                (host.cut if fault.kind.startswith("silent_") else host.stall)()
            try:
                if fault.kind.startswith("silent_long_") and fault.target != "hall":
                    await self._wait_broken(fault, since)
                else:
                    await asyncio.sleep(fault.hold_s)  # the fault itself: the link gone a while
            finally:
                host.heal()

    async def _wait_broken(self, fault: Fault, since: float) -> None:
        """Through a cut past the keep-alive: note when the cut host's will arrived."""
        listener = self.listener
        assert listener is not None
        who = self.unit_ids if fault.target == "units" else ["coordinator"]
        end = time.monotonic() + fault.hold_s
        seen = False
        while time.monotonic() < end:
            if not seen and any(listener.broken.get(w, 0.0) > since for w in who):
                self.detections.append(time.time() - since)
                seen = True
            await asyncio.sleep(0.05)  # the fault itself lasts until `end`; polling meanwhile
        if not seen:
            self.unrecovered.append(
                f"{fault.kind} at {since:.2f}: no will ('broken') within {fault.hold_s:.1f} s"
            )

    async def _restart(self, name: str, sig: signal.Signals) -> None:
        """Signal a process and wait until the supervisor has it running (and ready) again."""
        child = self.children[name]
        old = child.process
        assert old is not None
        old.send_signal(sig)
        try:
            await asyncio.wait_for(old.wait(), EXIT_WAIT_S)
        except TimeoutError:
            # A component that outlives SIGTERM is a finding (an operator's `kill` would not
            # stop it either); kill it so the soak goes on.
            self.unrecovered.append(f"{name} still running {EXIT_WAIT_S:g} s after {sig.name}")
            old.kill()
            await old.wait()
        deadline = time.monotonic() + RECOVERY_WAIT_S
        while child.process is old or (
            child.spec.ready is not None and not child.ready_event.is_set()
        ):
            if time.monotonic() > deadline:
                self.unrecovered.append(f"{name} not restarted within {RECOVERY_WAIT_S:.0f} s")
                return
            await asyncio.sleep(0.02)  # polling the supervisor, with a deadline
        if name == "broker":
            # Recovery: from the broker back up to every unit's state flowing again.
            took = await self._wait_flowing(time.time(), f"broker restart ({sig.name})")
            if took is not None:
                self.recoveries.append(took)

    # ---- the stop lane ------------------------------------------------------------------

    async def stop_lane(self, deadline: float) -> None:
        """Stops engaged (only between main-lane faults) and released, until `deadline`."""
        for fault in stop_faults(self.rng, self.cfg.faults):
            await asyncio.sleep(self.rng.uniform(*self.cfg.stop_gap_s))  # the schedule's pacing
            if time.monotonic() >= deadline:
                return
            async with self.calm:
                self.faults[fault.kind] += 1
                self.progress += 1
                if fault.kind == "estop_operator":
                    await self.publish(self.topics.fleet("estop"), "engaged|operator|soak")
                else:
                    topic = self.topics.device("device_stop", DEVICE)
                    await self.publish(topic, f"engaged|{DEVICE}|button", as_device=True)
                await self._wait_shown(True)
            await asyncio.sleep(fault.hold_s)  # the fault itself: the stop held this long
            await self.release()

    async def _wait_shown(self, engaged: bool, within: float = 10.0) -> None:
        """Until every unit's state shows the stop (or not), or `within` seconds."""
        listener = self.listener
        assert listener is not None
        deadline = time.monotonic() + within
        while time.monotonic() < deadline:
            shown = [listener.estop_shown.get(u) == engaged for u in self.unit_ids]
            if all(shown) and listener.stopped == engaged:
                return
            await asyncio.sleep(0.05)  # polling the listener, with a deadline

    async def release(self) -> None:
        """An operator's release on the latch; the coordinator clears the device's press."""
        await self.publish(self.topics.fleet("estop"), "released|operator|soak")
        # Moves are allowed from a release the listener then sees take (soak.check).
        self.recorded.append(Released(time.time()))
        await self._wait_released()

    async def _wait_released(self) -> None:
        """Until the listener sees the fleet released, releasing again every few seconds.

        A release given while the coordinator is down does not clear a device's press; the
        coordinator, back, reads the press as new and engages the latch again (the safe side):
        an operator then releases once more, and so does the soak (counted).
        """
        listener = self.listener
        assert listener is not None
        deadline = time.monotonic() + RECOVERY_WAIT_S
        again = time.monotonic() + RELEASE_AGAIN_S
        while listener.stopped:
            if time.monotonic() > deadline:
                self.unrecovered.append(
                    f"stop not released {RECOVERY_WAIT_S:.0f} s after the operator's release "
                    f"at {time.time() - RECOVERY_WAIT_S:.2f}"
                )
                return
            if time.monotonic() > again:
                self.release_repeats += 1
                await self.publish(self.topics.fleet("estop"), "released|operator|soak")
                self.recorded.append(Released(time.time()))
                again = time.monotonic() + RELEASE_AGAIN_S
            await asyncio.sleep(0.05)  # polling the listener, with a deadline

    async def publish(self, topic: str, payload: str, as_device: bool = False) -> None:
        """Publish retained at QoS 1 straight to the broker, retrying while it restarts."""
        deadline = time.monotonic() + RECOVERY_WAIT_S
        url = self.device_url if as_device else self.operator_url
        while True:
            try:
                client_id = self._client_id(f"op-{uuid.uuid4().hex[:4]}", as_device)
                async with connect_first(url, client_id) as c:
                    await c.publish(topic, payload.encode(), qos=1, retain=True)
                return
            except aiomqtt.MqttError:
                if time.monotonic() > deadline:
                    raise
                await asyncio.sleep(0.1)  # the broker is restarting: try again shortly

    async def _watchdog(
        self, quiet_s: float = STALL_S, work: asyncio.Task[None] | None = None
    ) -> None:
        """Say where every task waits, once, when the soak makes no progress for `quiet_s`,
        then cancel `work` so the run ends with the evidence instead of hanging.

        A 5-minute run was once seen injecting nothing after start-up, with every child healthy;
        this leaves the evidence in the log the next time instead of a silent hang.
        """
        seen, since = -1, time.monotonic()
        while True:
            await asyncio.sleep(min(5.0, quiet_s / 2))  # a coarse look: it only reports
            if self.progress != seen:
                seen, since = self.progress, time.monotonic()
            elif time.monotonic() - since > quiet_s:
                print(f"soak: no progress for {quiet_s:g} s; where each task waits:", file=self.log)
                for task in asyncio.all_tasks():
                    task.print_stack(file=self.log)
                self.unrecovered.append(f"the soak itself stalled: no progress for {quiet_s:g} s")
                self.stalled = True
                if work is not None:
                    work.cancel()
                return

    # ---- the end ------------------------------------------------------------------------

    async def drain(self) -> None:
        """Faults over: release any stop, stop the feed, and give every job time to end.

        A stop can come back during the drain: a coordinator restarted by the last faults reads
        a device's press whose clearing the broker's restart lost, and engages the latch again
        (the safe side). The operator releases it again, as they would at the hall.
        """
        listener = self.listener
        assert listener is not None
        if self._held():
            await self.release()
        feed = self.children["operator"]
        feed.spec.restart = False
        if feed.process is not None and feed.process.returncode is None:
            feed.process.send_signal(signal.SIGTERM)
            try:
                await asyncio.wait_for(feed.process.wait(), EXIT_WAIT_S)
            except TimeoutError:
                self.unrecovered.append(f"operator still running {EXIT_WAIT_S:g} s after SIGTERM")
                feed.process.kill()
                await feed.process.wait()
        deadline = time.monotonic() + self.cfg.drain_s
        while time.monotonic() < deadline:
            if listener.jobs and all(s in FINAL for s in listener.jobs.values()):
                return
            if self._held():
                self.release_repeats += 1
                await self.release()
            await asyncio.sleep(0.2)  # polling the listener, with a deadline

    async def read_unheard_ends(self) -> None:
        """The jobs the listener never heard end: their ends as the coordinator's history has
        them (its SQLite store, asked over the protocol), so a deaf listener loses no job.

        Each is recorded just after the listener's last word of the job, so that an end heard
        by neither still counts lost, and two ends in the history still count twice.
        """
        listener = self.listener
        assert listener is not None
        unheard = [job for job, state in listener.jobs.items() if state not in FINAL]
        if not unheard:
            return
        last_heard = {e.job: e.t for e in listener.events if isinstance(e, JobSeen)}
        since = datetime.now(UTC) - timedelta(seconds=self.cfg.minutes * 60 + 2 * 3600)
        try:
            client_id = self._client_id(f"hist-{uuid.uuid4().hex[:4]}")
            async with operator_session(self.operator_url, self.topics, client_id) as operator:
                for job in unheard:
                    page = await operator.job_history(since=since, job_id=job, limit=1000)
                    if not isinstance(page, JobHistoryPage):
                        self.unrecovered.append(f"job {job}: history refused: {page.reason}")
                        continue
                    ends = [e for e in page.entries if e.state in FINAL]
                    for n, entry in enumerate(ends, start=1):
                        at = max(entry.at.timestamp(), last_heard.get(job, 0.0) + 0.001 * n)
                        self.recorded.append(JobSeen(at, job, entry.state))
                    self.ends_from_history += bool(ends)
        except (aiomqtt.MqttError, TimeoutError) as exc:
            self.unrecovered.append(f"the coordinator's history not read: {exc}")
        print(
            f"[history    ] {len(unheard)} jobs not heard ending; "
            f"{self.ends_from_history} of them ended in the coordinator's history",
            file=self.log,
        )

    async def _start_and_inject(self) -> None:
        """Start the system, then both lanes of faults for the configured minutes."""
        await self.start()
        deadline = time.monotonic() + self.cfg.minutes * 60
        await asyncio.gather(self.main_lane(deadline), self.stop_lane(deadline))

    async def run(self) -> SoakResult:
        """Start, inject faults for the configured minutes, drain, stop, check."""
        work = asyncio.create_task(self._start_and_inject())
        watchdog = asyncio.create_task(self._watchdog(work=work))  # not the drain: it is bounded
        try:
            try:
                await work
            except asyncio.CancelledError:
                if not self.stalled:
                    raise  # the run itself was cancelled (Ctrl-C), not the watchdog's doing
            finally:
                watchdog.cancel()
                await asyncio.gather(watchdog, return_exceptions=True)
            await self.drain()
            await self.read_unheard_ends()
        finally:
            await self.sup.stop()
            for task in self.tasks:
                task.cancel()
            await asyncio.gather(*self.tasks, return_exceptions=True)
            for proxy in self.proxies:
                await proxy.close()
            self._close()
        assert self.listener is not None
        for at, report in self.listener.errors:
            print(f"[errors     ] {at:.2f} {report}", file=self.log)
        for at, said in self.listener.sessions:  # where the listener was, to read a gap against
            print(f"[listener   ] {at:.2f} {said}", file=self.log)
        # The stop as the listener saw it and the releases given, to read a verdict against.
        hall = self._hall_stops()
        stops = [
            e
            for e in (*self.listener.events, *self.recorded, *hall)
            if isinstance(e, Stop | Released)
        ]
        for event in sorted(stops, key=lambda e: e.t):
            if isinstance(event, Released):
                said = "released by the soak's operator"
            elif event.where == "hall":
                said = f"{'engaged' if event.engaged else 'released'} on the hall's broker"
            else:
                said = f"seen {'engaged' if event.engaged else 'released'} by the listener"
            print(f"[stop       ] {event.t:.2f} {said}", file=self.log)
        # And each fault, to read a move in a stop against what the fleet was going through.
        for start, end, kind in self.fault_times:
            print(f"[fault      ] {start:.2f} {kind}, flowing again at {end:.2f}", file=self.log)
        lag, when = self.listener.worst_lag
        print(
            f"[listener   ] a unit's state reached it {lag:.2f} s late at worst, at {when:.2f}",
            file=self.log,
        )
        events = [*self.listener.events, *self.recorded, *read_truth(self.truth), *hall]
        limits = SoakLimits(self.cfg.step_s, stranded_s=self.cfg.stranded_s)
        verdict = check(events, limits)
        fault_s: defaultdict[str, list[float]] = defaultdict(list)  # fault to flowing again
        for start, end, kind in self.fault_times:
            fault_s[kind].append(end - start)
        return SoakResult(
            self.cfg.minutes,
            self.cfg.units,
            self.faults,
            verdict,
            self.recoveries,
            self.unrecovered,
            self.release_repeats,
            dict(fault_s),
            self.detections,
            self._node_recoveries(),
            self.cfg.cluster,
            self._extra(),
            self.ends_from_history,
        )

    def _node_recoveries(self) -> dict[str, list[float]]:
        """Per node fault's kind, the seconds to the fleet moving again (a cluster's)."""
        return {}

    def _held(self) -> bool:
        """Whether the fleet is held by a stop the soak's operator should release."""
        assert self.listener is not None
        return self.listener.stopped

    def _extra(self) -> dict[str, object]:
        """Figures of the topology's own, for the JSON."""
        return {}
