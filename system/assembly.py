"""How the system is put together: broker, coordinator and units (and, as processes, the dashboard
and the job feed), in threads of this process or as supervised processes — one switch.

`gridfleet up` runs it as processes, `gridfleet simulate`, `gridfleet bench system` and the tests
in threads (where the ground-truth world simulation can be read).
"""

from __future__ import annotations

import asyncio
import os
import re
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TextIO

from gridfleet.accounts import Accounts, load_accounts
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.broker.origins import LOCAL_NAMES, dashboard_origins
from gridfleet.config import with_ca_file, with_credentials
from gridfleet.coordinator.audit import Identity
from gridfleet.coordinator.store import default_db_path
from gridfleet.coordinator.window import DEFAULT_WINDOW
from gridfleet.errors import ConfigError
from gridfleet.ports import free_port
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.scenario import Scenario, with_units
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.supervisor import Child, ChildSpec, Supervisor
from gridfleet.system.threads import ServiceThread, coordinator_thread, fleet_thread

if TYPE_CHECKING:
    from gridfleet.coordinator.shell import CoordinatorShell
    from gridfleet.robots.fleet import Fleet

Mode = Literal["threads", "processes"]

BROKER_READY = re.compile(r"listening on (mqtts?://\S+)(?: and (wss?://\S+))?")
# A broker on every address is reached by its neighbours on this machine through loopback.
LOOPBACK_OF = {"0.0.0.0": "127.0.0.1"}
DASHBOARD_READY = re.compile(r"(https?://\S+)")


@dataclass(frozen=True)
class SystemSpec:
    """What to run: a scenario's coordinator and units on one broker, and how."""

    scenario: Scenario
    broker: str | None = None  # None: an embedded broker of our own
    broker_ws: str | None = None  # the external broker's websocket URL (for the dashboard)
    root: str = DEFAULT_ROOT
    step_s: float = 0.5
    window: int = DEFAULT_WINDOW  # squares a unit may be released ahead (coordinator.window)
    db_path: Path | None = None  # the coordinator's job store (None: per user, as a service)
    seed: int = 0
    energy_policy: str = "gridfleet"  # the coordinator's (coordinator/energy.py POLICIES)
    coordinator_id: str | None = None  # default: 'coordinator', its client id per root
    sensors_see_units: bool = True  # threads only: sensors blind to units test the orders alone
    own_broker: Mode = "threads"  # where an embedded broker runs when the services are threads
    mqtt_port: int = 0  # an embedded broker's ports (0: free ones)
    ws_port: int | None = 0  # None: no websocket listener
    dashboard_port: int | None = None  # processes only: serve the dashboard on this port
    accounts: Accounts | None = field(default=None, repr=False)  # threads: each part its own
    # Each part logs in as its own account from this file: processes read it themselves (no
    # password on a command line); threads load it when `accounts` is not given.
    accounts_file: Path | None = None
    listen: str = "127.0.0.1"  # processes: where an embedded broker and the dashboard listen
    tls_cert: Path | None = None  # processes: an embedded broker's certificate and key (TLS)
    tls_key: Path | None = None
    ca_file: Path | None = None  # processes: the CA the parts trust for an embedded TLS broker
    unit_workers: int = 1  # processes only: the units over this many processes, one world
    truth: Path | None = None  # processes only: the units write the world's ground truth here
    feed: bool = False  # processes only: submit the scenario's jobs and goals
    demo: bool = False  # with feed: keep random feasible jobs coming
    robots: bool = (
        True  # processes only: run the scenario's simulated units (not: they join from elsewhere)
    )
    vehicles: Path | None = None  # processes only: VDA 5050 vehicles, their adapter's file
    metrics_port: int | None = None  # the coordinator's metrics on 127.0.0.1 (0: a free port)
    alerts: bool = False  # processes only: the alerts process (`gridfleet alerts`)
    alerts_config: Path | None = None  # its rules and webhook ([alerts]): no URL on a command line


def cli(*args: str) -> list[str]:
    """The command line of a `gridfleet` subcommand run by this interpreter."""
    return [sys.executable, "-m", "gridfleet", *args]


@dataclass
class System:
    """A running system: where its broker is, and its parts."""

    url: str = ""
    ws_url: str | None = None
    dashboard_url: str | None = None
    threads: dict[str, ServiceThread[Any]] = field(default_factory=dict)
    children: dict[str, Child] = field(default_factory=dict)
    supervisor: Supervisor | None = None
    broker_thread: BrokerThread | None = None

    @property
    def coordinator(self) -> ServiceThread[CoordinatorShell]:
        """The coordinator's thread (threads mode)."""
        return self.threads["coordinator"]

    @property
    def fleet(self) -> ServiceThread[Fleet]:
        """The units' thread (threads mode)."""
        return self.threads["robots"]


class Assembly:
    """Starts a SystemSpec in threads or processes and stops it in reverse order.

    `async with Assembly(spec, "threads") as system:`; or, for synchronous tests, `start_threads()`
    and `stop()`.
    """

    def __init__(
        self, spec: SystemSpec, mode: Mode = "threads", supervisor: Supervisor | None = None
    ):
        if mode == "threads" and (spec.dashboard_port is not None or spec.feed):
            raise ConfigError("the dashboard and the feed run only as processes")
        in_threads_only = (spec.seed, spec.coordinator_id, spec.sensors_see_units, spec.accounts)
        if mode == "processes" and in_threads_only != (0, None, True, None):
            raise ConfigError(
                "seed, coordinator id, blind sensors and loaded accounts are set only in threads "
                "(processes take accounts_file)"
            )
        in_processes_only = (spec.listen, spec.tls_cert, spec.tls_key, spec.ca_file)
        if mode == "threads" and in_processes_only != ("127.0.0.1", None, None, None):
            raise ConfigError("the listen address and TLS are set only as processes")
        if mode == "threads" and spec.alerts:
            raise ConfigError("the alerts process runs only as a process")
        if mode == "threads" and (spec.unit_workers != 1 or spec.truth is not None):
            raise ConfigError("unit workers and a truth file are set only as processes")
        if spec.unit_workers < 1:
            raise ConfigError(f"{spec.unit_workers} unit workers: give at least 1")
        self.spec = spec
        self.mode = mode
        self.system = System(supervisor=supervisor)
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._quiet: TextIO | None = None

    # ---- threads ------------------------------------------------------------------------

    def start_threads(self, timeout: float = 60.0) -> System:
        """Start broker (if ours), coordinator and units in threads; blocks until each is ready."""
        spec, system = self.spec, self.system
        try:
            accounts = self._accounts()
            if system.url:
                pass  # our broker already runs as a process (see __aenter__)
            elif spec.broker is None:
                settings = BrokerSettings(
                    port=spec.mqtt_port,
                    ws_port=spec.ws_port,
                    accounts=accounts,
                    root=spec.root,
                )
                system.broker_thread = BrokerThread(settings)
                system.broker_thread.start()
                system.url = system.broker_thread.url
                system.ws_url = system.broker_thread.ws_url if spec.ws_port is not None else None
            else:
                system.url, system.ws_url = spec.broker, spec.broker_ws
            db_path = spec.db_path
            if db_path is None:
                self._tmp = tempfile.TemporaryDirectory(prefix="gridfleet-")
                db_path = Path(self._tmp.name) / "jobs.db"
            scenario = with_units(spec.scenario)
            coordinator_url = system.url
            if accounts is not None:
                login = accounts.get("coordinator")
                coordinator_url = with_credentials(system.url, login.name, login.password)
            metrics = None
            if spec.metrics_port is not None:
                from gridfleet.metrics import MetricsOptions  # prometheus_client: only when asked

                metrics = MetricsOptions(spec.metrics_port)
            coordinator = coordinator_thread(
                scenario,
                coordinator_url,
                root=spec.root,
                step_s=spec.step_s,
                db_path=db_path,
                seed=spec.seed,
                energy_policy=spec.energy_policy,
                client_id=spec.coordinator_id,
                window=spec.window,
                metrics=metrics,
                # Our own broker with accounts drops a request naming another account's id.
                identity=Identity(accounts, vouched=spec.broker is None),
            )
            system.threads["coordinator"] = coordinator.start(timeout)
            fleet = fleet_thread(
                scenario,
                system.url,
                root=spec.root,
                step_s=spec.step_s,
                sensors_see_units=spec.sensors_see_units,
                accounts=accounts,
            )
            system.threads["robots"] = fleet.start(timeout)
        except BaseException:
            self.stop()
            raise
        return system

    def _accounts(self) -> Accounts | None:
        """The accounts the threads log in with: given, or read from the spec's file."""
        if self.spec.accounts is None and self.spec.accounts_file is not None:
            return load_accounts(self.spec.accounts_file)
        return self.spec.accounts

    @property
    def logins(self) -> list[str]:
        """The flags that make a child process log in as its own account."""
        # The file, never the passwords, on the command lines: `ps` shows those to everyone.
        return (
            [] if self.spec.accounts_file is None else ["--accounts", str(self.spec.accounts_file)]
        )

    @property
    def tls_files(self) -> list[str]:
        """The flags that give a child process the embedded broker's certificate and key."""
        cert, key = self.spec.tls_cert, self.spec.tls_key
        return (
            [] if cert is None or key is None else ["--tls-cert", str(cert), "--tls-key", str(key)]
        )

    def dashboard_origins(self, port: int) -> tuple[str, ...]:
        """The origins of the dashboard on `port`: the only pages the broker lets in without
        accounts (by 127.0.0.1, localhost, and the address it listens on)."""
        hosts = dict.fromkeys([*LOCAL_NAMES, self.spec.listen])
        for everywhere in ("0.0.0.0", "::"):
            hosts.pop(everywhere, None)
        return dashboard_origins(port, tls=self.spec.tls_cert is not None, hosts=hosts)

    def stop(self, timeout: float = 60.0) -> None:
        """Stop every thread in reverse order (units say offline first), then our broker."""
        errors: list[BaseException] = []
        for name in reversed(list(self.system.threads)):
            try:
                self.system.threads.pop(name).stop(timeout)
            except BaseException as exc:  # stop the rest, then raise the first
                errors.append(exc)
        if self.system.broker_thread is not None:
            self.system.broker_thread.stop()
            self.system.broker_thread = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        if errors:
            raise errors[0]

    # ---- processes ----------------------------------------------------------------------

    async def start_processes(self) -> System:
        """Start every component as a supervised child process, in order."""
        spec, system = self.spec, self.system
        if system.supervisor is None:
            system.supervisor = Supervisor()
        sup = system.supervisor
        logins = self.logins
        dashboard_port = spec.dashboard_port
        if dashboard_port == 0:  # the broker must know the page's origin before it is served
            dashboard_port = free_port()
        if spec.broker is None:
            pages = () if dashboard_port is None else self.dashboard_origins(dashboard_port)
            system.url, system.ws_url = await start_broker_process(sup, spec, logins, pages)
            if spec.ca_file is not None:
                system.url = with_ca_file(system.url, str(spec.ca_file))
        else:
            if spec.dashboard_port is not None and not spec.broker_ws:
                raise ConfigError("with --broker, also give --broker-ws for the dashboard")
            system.url, system.ws_url = spec.broker, spec.broker_ws
        common = ["--broker", system.url, "--root", spec.root, *logins]
        step = ["--step", str(spec.step_s)]
        scenario = str(spec.scenario.path)
        # The scenario itself, not only its map: the coordinator takes its chargers, places and
        # [charging].
        coordinator = ["coordinator", *common, "--map", scenario, *step]
        coordinator += ["--window", str(spec.window), "--energy-policy", spec.energy_policy]
        if spec.db_path is not None:
            coordinator += ["--db", str(spec.db_path)]
        if spec.metrics_port is not None:
            coordinator += ["--metrics", str(spec.metrics_port)]
        if spec.broker is None and spec.accounts_file is not None:
            # Our own broker drops a request or latch naming an id its account does not own.
            coordinator += ["--vouched-senders"]
        system.children["coordinator"] = await sup.start(
            ChildSpec("coordinator", cli(*coordinator))
        )
        if spec.alerts:
            system.children["alerts"] = await sup.start(self._alerts(common))
        if spec.robots:
            system.children["robots"] = await sup.start(self._robots(common, step))
        if spec.vehicles is not None:
            adapter = cli("vda5050", *common, "--vehicles", str(spec.vehicles))
            adapter += ["--scenario", scenario, *step]
            system.children["vda5050"] = await sup.start(ChildSpec("vda5050", adapter))
        if dashboard_port is not None:
            assert system.ws_url is not None
            dashboard = cli(
                "dashboard",
                "--broker-ws",
                system.ws_url,
                "--root",
                spec.root,
                "--host",
                spec.listen,
                "--port",
                str(dashboard_port),
                "--scenario",
                scenario,
                *logins,
                *self.tls_files,
                # Its own way to the broker: the HTTP API's (and, with logins, the audit's).
                "--audit-broker",
                system.url,
                # Our own broker checks a page session's own password, taken back at logout.
                *(["--session-passwords"] if logins and spec.broker is None else []),
            )
            child = await sup.start(ChildSpec("dashboard", dashboard, ready=DASHBOARD_READY))
            system.children["dashboard"] = child
            assert child.ready_match is not None
            system.dashboard_url = child.ready_match.group(1)
        if spec.feed:
            feed = cli("feed", *common, "--scenario", scenario, *step, *(["--demo"] * spec.demo))
            system.children["operator"] = await sup.start(
                ChildSpec("operator", feed, restart=spec.demo)
            )
        return system

    def _alerts(self, common: list[str]) -> ChildSpec:
        """The alerts process: its rules and webhook from a file, never on its command line."""
        config = self.spec.alerts_config
        alerts = cli("alerts", *common, *([] if config is None else ["--config", str(config)]))
        return ChildSpec("alerts", alerts)

    def _robots(self, common: list[str], step: list[str]) -> ChildSpec:
        """The simulated units' process: they resume where they stood, beside the job store."""
        spec = self.spec
        units_state = units_state_path(spec.db_path)
        units_state.parent.mkdir(parents=True, exist_ok=True)
        scenario = str(spec.scenario.path)
        robots = cli("robots", *common, "--scenario", scenario, *step, "--state", str(units_state))
        if spec.unit_workers > 1:
            robots += ["--workers", str(spec.unit_workers)]
        if spec.truth is not None:
            robots += ["--truth", str(spec.truth)]
        return ChildSpec("robots", robots)

    # ---- either -------------------------------------------------------------------------

    async def __aenter__(self) -> System:
        if self.mode == "threads":
            if self.spec.broker is None and self.spec.own_broker == "processes":
                # Out of this interpreter, so it shares no lock with the services' threads. An
                # overloaded amqtt can take long to drain when stopped: it has no queue limit.
                self._quiet = open(os.devnull, "w")  # noqa: SIM115 - closed in _stop_processes
                self.system.supervisor = Supervisor(out=self._quiet, stop_timeout=20.0)
                try:
                    self.system.url, self.system.ws_url = await start_broker_process(
                        self.system.supervisor, self.spec, self.logins
                    )
                    return await asyncio.to_thread(self.start_threads)
                except BaseException:
                    await self._stop_processes()
                    raise
            return await asyncio.to_thread(self.start_threads)
        try:
            return await self.start_processes()
        except BaseException:
            await self._stop_processes()
            raise

    async def __aexit__(self, *exc: Any) -> None:
        try:
            if self.mode == "threads":
                await asyncio.to_thread(self.stop)
        finally:
            await self._stop_processes()  # last: the broker, after the services

    async def _stop_processes(self) -> None:
        if self.system.supervisor is not None:
            await self.system.supervisor.stop()
        if self._quiet is not None:
            self._quiet.close()
            self._quiet = None


async def start_broker_process(
    supervisor: Supervisor,
    spec: SystemSpec,
    logins: list[str] | None = None,
    ws_origins: tuple[str, ...] = (),
) -> tuple[str, str | None]:
    """An embedded broker as a supervised child process; the MQTT and websocket URLs its
    neighbours on this machine use (loopback when it listens on every address). `ws_origins`:
    the web pages its websocket listener lets in (none given: `gridfleet broker`'s default)."""
    argv = ["broker", "--host", spec.listen, "--port", str(spec.mqtt_port), "--root", spec.root]
    argv += ["--no-ws"] if spec.ws_port is None else ["--ws-port", str(spec.ws_port)]
    for origin in ws_origins:
        argv += ["--ws-origin", origin]
    if spec.tls_cert is not None and spec.tls_key is not None:
        argv += ["--tls-cert", str(spec.tls_cert), "--tls-key", str(spec.tls_key)]
    argv += logins or []
    child = await supervisor.start(ChildSpec("broker", cli(*argv), ready=BROKER_READY))
    assert child.ready_match is not None
    url = child.ready_match.group(1)
    host = LOOPBACK_OF.get(spec.listen)
    if host is not None:
        url = url.replace(f"//{spec.listen}:", f"//{host}:", 1)
    return url, child.ready_match.group(2)


def units_state_path(db_path: Path | None) -> Path:
    """Where `up`'s units keep their squares and loads: beside the coordinator's job store."""
    jobs = db_path if db_path is not None else default_db_path()
    return jobs.with_name(f"{jobs.stem}.units.sqlite3")
