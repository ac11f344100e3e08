"""The API as a client of the fleet: per account, one MQTT connection logged in as that account.

Like `gridfleet job`, the API sends requests to the coordinator (re-sent until replied, by
gridfleet.console.operator's Operator) and reads its retained views; it keeps no copy of the
truth. Each account the API serves gets its own connection, client id `<account>-api` (per
topic root), so the broker's rules and the audit see that account: with session passwords
(the embedded broker checks them) a password minted for the connection, else the account's.
The connections run in one asyncio loop in a thread of their own; the server's threads hand it
work and wait for the answer (`FleetClients.run`).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import hashlib
import logging
import secrets
import threading
import time
from collections.abc import Awaitable, Callable, Coroutine
from typing import Any, TypeVar

import aiomqtt

from gridfleet.bus import connect_first
from gridfleet.config import owned_client_id, redacted, with_credentials
from gridfleet.console.operator import RETRY_S, Operator
from gridfleet.dashboard.api.events import ChangeTracker, EventLog
from gridfleet.dashboard.api.models import JobRequest, UnitView
from gridfleet.dashboard.api.problems import ApiProblem
from gridfleet.dashboard.login import SESSION_S
from gridfleet.errors import GridfleetError, ProtocolError
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    TOPICS,
    Connection,
    Factsheet,
    FleetMap,
    Reply,
    Routes,
    SubmitJob,
    Topics,
    UnitState,
    ZonesView,
    decode,
)
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.protocol.messages import EnergyView, Message
from gridfleet.protocol.stop import STOP_KINDS
from gridfleet.session_login import make_session_password
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.dashboard.api")
T = TypeVar("T")
M = TypeVar("M", bound=Message)
UNIT_KINDS = ("state", "factsheet", "connection")
UNIT_MODELS: dict[str, type[Message]] = {
    "state": UnitState,
    "factsheet": Factsheet,
    "connection": Connection,
}
SETTLE_S = 1.0  # the retained views have come once the coordinator's status has, or after this
RECONNECT_S = (0.5, 10.0)  # the first pause before connecting again, and the longest


class FleetView(Operator):
    """An Operator that also keeps the views the API serves: the map and its places, routes
    (controls and notes), zones, energy, and each unit's state, factsheet and connection."""

    def __init__(
        self,
        client: aiomqtt.Client,
        topics: Topics,
        client_id: str,
        retry_s: float = RETRY_S,
        changed: Callable[[FleetView, str], None] | None = None,
    ) -> None:
        super().__init__(client, topics, client_id, retry_s)
        self.fleet_map: FleetMap | None = None
        self.routes: Routes | None = None
        self.zones: ZonesView | None = None
        self.energy: EnergyView | None = None
        self.views_changed = asyncio.Event()  # set on every view, for waits on an effect
        self.changed = changed
        self.started = asyncio.get_running_loop().time()
        # Each unit's retained payloads, decoded only when asked (states come every step).
        self._units: dict[str, dict[str, tuple[bytes, Message | None]]] = {}

    async def start(self) -> None:
        """Subscribe to the views of the units, zones and energy, then to the Operator's."""
        t = self.topics
        for kind in UNIT_KINDS:
            await self.client.subscribe(t.all_units(kind), qos=SUBSCRIBE_QOS)
        for kind in ("zones", "energy"):
            await self.client.subscribe(t.fleet(kind), qos=SUBSCRIBE_QOS)
        await super().start()  # the coordinator's status last: it marks the end of the rest

    def handle(self, topic: str, payload: bytes) -> None:
        """Take one message into the views; the Operator's kinds to the Operator."""
        try:
            kind, source = self.topics.parse(topic)
            if kind in UNIT_KINDS and source is not None:
                self._take_unit(source, kind, payload)
            elif kind == "map":
                self.fleet_map = decode(FleetMap, payload, TOPICS["map"].max_bytes)
                self.obstacles = frozenset(self.fleet_map.obstacles)
            elif kind == "routes":
                self.routes = decode(Routes, payload, TOPICS["routes"].max_bytes)
                self.planned_units = set(self.routes.routes)
                self.routes_changed.set()
            elif kind in ("zones", "energy"):
                self._take_view(kind, payload)
            else:
                super().handle(topic, payload)
        except ProtocolError as exc:
            log.warning("api: ignored a bad message on %s: %s", topic, exc)
            return
        self.views_changed.set()
        if self.changed is not None:
            self.changed(self, kind)

    def _take_unit(self, unit: str, kind: str, payload: bytes) -> None:
        """Keep a unit's payload (an empty one clears it: a removed unit, protocol.md §6.11)."""
        kept = self._units.setdefault(unit, {})
        if payload:
            kept[kind] = (payload, None)
        else:
            kept.pop(kind, None)
            if not kept:
                del self._units[unit]

    def _take_view(self, kind: str, payload: bytes) -> None:
        """The zones or energy view (an empty payload: cleared)."""
        limit = TOPICS[kind].max_bytes
        if kind == "zones":
            self.zones = decode(ZonesView, payload, limit) if payload else None
        else:
            self.energy = decode(EnergyView, payload, limit) if payload else None

    def _unit_part(self, unit: str, kind: str, model: type[M]) -> M | None:
        """A unit's decoded message of `kind` (None: none, or not valid)."""
        kept = self._units.get(unit, {})
        entry = kept.get(kind)
        if entry is None:
            return None
        payload, decoded = entry
        if decoded is None:
            try:
                decoded = decode(model, payload, TOPICS[kind].max_bytes)
            except ProtocolError as exc:
                log.info("api: unit %s: its %s is not valid: %s", unit, kind, exc)
                return None
            kept[kind] = (payload, decoded)
        assert isinstance(decoded, model)
        return decoded

    def unit_ids(self) -> list[str]:
        """Every unit the views know of, sorted."""
        routes = set() if self.routes is None else set(self.routes.routes)
        return sorted(set(self._units) | routes)

    def unit(self, unit: str) -> UnitView | None:
        """One unit as the views show it (None: they know no such unit)."""
        if unit not in self._units and (self.routes is None or unit not in self.routes.routes):
            return None
        state = self._unit_part(unit, "state", UnitState)
        factsheet = self._unit_part(unit, "factsheet", Factsheet)
        connection = self._unit_part(unit, "connection", Connection)
        route = None if self.routes is None else self.routes.routes.get(unit)
        energy = None if self.energy is None else self.energy.units.get(unit)
        return UnitView(
            id=unit,
            connection=None if connection is None else connection.state,
            status=None if state is None else state.status,
            position=None if state is None else state.position,
            job_id=None if state is None else state.job_id,
            battery_pct=None if state is None else state.battery_pct,
            charging=state is not None and state.charging,
            control=None if route is None else route.control,
            note=None if route is None else route.note,
            state=state,
            factsheet=factsheet,
            route=route,
            energy=energy,
        )

    async def submit(self, job: JobRequest, derived: str | None, timeout: float) -> Reply:
        """Queue `job`; with a derived id (Idempotency-Key) as both its job id and request id."""
        fields: dict[str, object] = {
            "pickup": job.pickup,
            "dropoff": job.dropoff,
            "mass_kg": job.mass_kg,
            "priority": job.priority,
            "job_id": derived,
        }
        if derived is None:
            request = self._made("submit_job", SubmitJob, fields)
        else:
            request = SubmitJob(
                header=self.stamp("submit_job"),
                request_id=derived,
                reply_to=self.client_id,
                **fields,  # type: ignore[arg-type]
            )
        answer = await self._send("submit_job", request, timeout)
        assert isinstance(answer, Reply)
        return answer

    async def settled(self) -> None:
        """Until the retained views have come (the coordinator's status marks their end)."""
        left = SETTLE_S - (asyncio.get_running_loop().time() - self.started)
        if left > 0 and not self.coordinator_heard.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.coordinator_heard.wait(), left)

    def is_settled(self) -> bool:
        """Whether the retained views have come (without waiting)."""
        waited = asyncio.get_running_loop().time() - self.started
        return self.coordinator_heard.is_set() or waited >= SETTLE_S

    async def until(self, test: Callable[[], T | None], wait_s: float) -> T | None:
        """`test()` once it gives something, as the views change, for up to `wait_s`."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + wait_s
        while True:
            found = test()
            if found is not None:
                return found
            left = deadline - loop.time()
            if left <= 0:
                return None
            self.views_changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.views_changed.wait(), left)


class Link:
    """One account's connection, kept up (reconnecting) while the dashboard runs."""

    def __init__(
        self,
        name: str,
        password: str | None,
        url: str,
        topics: Topics,
        session_passwords: bool,
        events: EventLog,
        tracker: ChangeTracker,
        retry_s: float = RETRY_S,
    ) -> None:
        self.name = name
        self.password = password
        self.url = url
        self.topics = topics
        self.session_passwords = session_passwords
        self.events = events
        self.tracker = tracker
        self.retry_s = retry_s
        self.client_id = api_client_id(name, topics)
        self.view: FleetView | None = None
        self.connected = asyncio.Event()
        self.problem: str | None = None  # why it is not connected, in words
        self.baselined = False  # the first views have come: changes from now on are events
        self._task: asyncio.Task[None] | None = None

    def launch(self) -> None:
        """Start keeping the connection up (in the loop's thread)."""
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run())

    async def close(self) -> None:
        """Stop and disconnect."""
        if self._task is not None:
            await cancel_and_wait(self._task)

    def login(self) -> str:
        """The broker URL this connection logs in with (a fresh session password each time)."""
        if not self.name or self.password is None:
            return self.url
        password = self.password
        if self.session_passwords:
            sid = secrets.token_urlsafe(16)
            password = make_session_password(
                self.name, self.password, sid, int(time.time() + SESSION_S)
            )
        return with_credentials(self.url, self.name, password)

    async def _run(self) -> None:
        pause = RECONNECT_S[0]
        while True:
            try:
                async with connect_first(self.login(), self.client_id) as client:
                    view = FleetView(
                        client, self.topics, self.client_id, self.retry_s, self._changed
                    )
                    await view.start()
                    self.view, self.problem, pause = view, None, RECONNECT_S[0]
                    self.connected.set()
                    log.info("api: connected to the broker as %s", self.name or "(no account)")
                    await view.listen()
            except aiomqtt.MqttError as exc:
                who = f" as {self.name}" if self.name else ""
                self.problem = f"the API cannot reach the broker {redacted(self.url)}{who}: {exc}"
                log.warning("api: %s; trying again in %.1f s", self.problem, pause)
            except Exception as exc:  # a bug, or an account the API cannot log in as
                self.problem = (
                    f"the API's connection as {self.name or '(no account)'} failed: {exc}"
                )
                log.exception("api: %s; trying again in %.1f s", self.problem, pause)
            finally:
                self.view = None
                self.connected.clear()
            await asyncio.sleep(pause)  # pacing of reconnection attempts
            pause = min(2 * pause, RECONNECT_S[1])

    def _changed(self, view: FleetView, kind: str) -> None:
        """Events for what a view changed (the views as they first settle are the baseline)."""
        tracker = self.tracker
        if not self.baselined:
            if view.is_settled():
                tracker.baseline(view.jobs, view.zones, view.stop, view.coordinator)
                self.baselined = True
            return
        if kind == "jobs" and view.jobs is not None:
            found = tracker.jobs(view.jobs)
        elif kind == "zones":
            found = tracker.zones(view.zones)
        elif kind in STOP_KINDS:
            found = tracker.stop(view.stop, view.coordinator)
        elif kind == "coordinator":
            found = tracker.coordinator(view.coordinator)
        else:
            return
        if found:
            self.events.add(found)

    async def ready(self, wait_s: float) -> FleetView:
        """The connection's views, once connected and settled; 503 when it cannot be had."""
        if self.view is None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.connected.wait(), wait_s)
        view = self.view
        if view is None:
            raise ApiProblem(
                "no_broker", self.problem or "the API is connecting to the broker: try again"
            )
        await view.settled()
        return view


def api_client_id(account: str, topics: Topics) -> str:
    """The API's client id for `account` (also its requests' sender, so an id): `api`, made
    one the account owns (`operator-api`), and one per topic root but the default."""
    base = "api"
    if topics.root != DEFAULT_ROOT:
        base += "-" + hashlib.sha256(topics.root.encode()).hexdigest()[:8]
    return owned_client_id(account or None, base)


class FleetClients:
    """The API's links to the fleet, one per account, in one event loop of their own."""

    def __init__(
        self, url: str, topics: Topics, session_passwords: bool = False, retry_s: float = RETRY_S
    ) -> None:
        self.url = url
        self.topics = topics
        self.session_passwords = session_passwords
        self.retry_s = retry_s
        self._lock = threading.Lock()
        self._links: dict[str, Link] = {}
        self._logs: dict[str, tuple[EventLog, ChangeTracker]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None

    def _started_loop(self) -> asyncio.AbstractEventLoop:
        """The links' loop, started at the first need (the lock held)."""
        if self._loop is None:
            loop = asyncio.new_event_loop()
            self._thread = threading.Thread(
                target=loop.run_forever, name="gridfleet-api", daemon=True
            )
            self._thread.start()
            self._loop = loop
        return self._loop

    def link(self, name: str, password: str | None) -> Link:
        """Account `name`'s link (made at its first use; made anew when its password changed)."""
        with self._lock:
            loop = self._started_loop()
            link = self._links.get(name)
            if link is not None and link.password == password:
                return link
            if link is not None:
                asyncio.run_coroutine_threadsafe(link.close(), loop)
            events, tracker = self._logs.setdefault(name, (EventLog(), ChangeTracker()))
            link = Link(
                name,
                password,
                self.url,
                self.topics,
                self.session_passwords,
                events,
                tracker,
                self.retry_s,
            )
            self._links[name] = link
            loop.call_soon_threadsafe(link.launch)
            return link

    def run(self, work: Coroutine[Any, Any, T], timeout: float) -> T:
        """Run `work` in the links' loop and wait for its result (ApiProblem when it is late)."""
        with self._lock:
            loop = self._started_loop()
        future = asyncio.run_coroutine_threadsafe(work, loop)
        try:
            return future.result(timeout)
        except concurrent.futures.TimeoutError:
            future.cancel()
            raise ApiProblem(
                "no_reply", f"no answer from the fleet within {timeout:.0f} s: try again"
            ) from None

    def close(self, timeout: float = 5.0) -> None:
        """Disconnect every link and end the loop."""
        with self._lock:
            loop, links = self._loop, list(self._links.values())
            self._links.clear()
            self._loop = None
        if loop is None:
            return

        async def close_all() -> None:
            for link in links:
                await link.close()

        with contextlib.suppress(concurrent.futures.TimeoutError, RuntimeError):
            asyncio.run_coroutine_threadsafe(close_all(), loop).result(timeout)
        loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(timeout)


async def guarded(work: Awaitable[T]) -> T:
    """`work`, its fleet errors as problems: no reply in time, no broker (503)."""
    try:
        return await work
    except aiomqtt.MqttError as exc:
        raise ApiProblem("no_broker", f"the API lost the broker: {exc}") from None
    except GridfleetError as exc:
        if isinstance(exc, ProtocolError):
            raise ApiProblem("bad_request", str(exc)) from None
        raise ApiProblem("no_reply", str(exc)) from None


async def require_online(view: FleetView) -> None:
    """503 at once unless a coordinator is online (its retained status says so)."""
    status = view.coordinator
    if status is not None and status.state == "online":
        return
    root = view.topics.root
    if status is None:
        raise ApiProblem(
            "not_online",
            f"no coordinator has said it runs under root {root!r}: is it started?",
        )
    raise ApiProblem(
        "not_online", f"the coordinator is not online (it says {status.state}): try again soon"
    )
