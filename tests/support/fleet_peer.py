"""Typed stand-ins for what the units and the coordinator publish, for tests that play them.

A `UnitPeer` publishes what one unit does (connection, factsheet, state, direction) and reads the
orders it is sent, a `CoordinatorPeer` publishes what the coordinator does (map, jobs view,
routes, status, replies, error reports). Each message is built from the protocol's own models
(`gridfleet.protocol`), stamped with a header of its sender and published through an `MqttProbe`
with the QoS and retain flag protocol.md gives its topic (`gridfleet.outbound.Outbound.of`).
Every method that publishes returns the message it published, so a test can compare what
arrives with what was sent.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Literal

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.outbound import Outbound, error_report
from gridfleet.protocol import (
    Connection,
    CoordinatorStatus,
    ErrorReport,
    EventEntry,
    EventsView,
    Factsheet,
    FleetMap,
    HeaderStamper,
    JobsView,
    JobView,
    Leds,
    Order,
    Reply,
    Routes,
    RouteView,
    Sensors,
    Topics,
    UnitState,
    decode,
    encode_direction,
)
from gridfleet.protocol.messages import (
    FINAL_JOB_STATES,
    FINISHED_LISTED,
    JobState,
    Message,
    UnitStatus,
)

from support.probe import MqttProbe

Liveness = Literal["online", "offline", "broken"]  # `connection` and `coordinator/status` state
Mode = Literal["coordinated", "standalone"]
ALL_FREE = Sensors(N="free", E="free", S="free", W="free")


def publish(probe: MqttProbe, kind: str, topic: str, message: Message | bytes) -> None:
    """Publish `message` on `topic` of `kind` with the QoS and retain flag protocol.md gives it."""
    out = Outbound.of(kind, topic, message)
    probe.publish(out.topic, out.payload, qos=out.qos, retain=out.retain)


def leds_for(direction: Direction | None, stopped: bool = False) -> Leds:
    """The LEDs a unit shows: the one of its direction, none without one, all four when stopped.

    The product's rule is `robots.unit.UnitLogic.leds`, a method that reads a running unit's own
    stop and direction; neither it nor `gridfleet.protocol` offers it as a function of the two.
    """
    if stopped:
        return Leds(N=True, E=True, S=True, W=True)
    return Leds(
        N=direction is Direction.N,
        E=direction is Direction.E,
        S=direction is Direction.S,
        W=direction is Direction.W,
    )


class UnitPeer:
    """Publishes what one unit publishes, as that unit (its id is the headers' sender)."""

    def __init__(self, probe: MqttProbe, topics: Topics, unit: str) -> None:
        self.probe = probe
        self.topics = topics
        self.unit = unit
        self.stamp = HeaderStamper(unit)

    def connection(self, state: Liveness) -> Connection:
        """`units/<id>/connection`: online, offline, or broken (what its last will says)."""
        message = Connection(header=self.stamp("connection"), state=state)
        publish(self.probe, "connection", self.topics.unit("connection", self.unit), message)
        return message

    def factsheet(
        self, capacity_kg: float, color: str = "#607d8b", step_period_s: float = 0.05
    ) -> Factsheet:
        """`units/<id>/factsheet`: what the unit can carry, its step period and colour."""
        message = Factsheet(
            header=self.stamp("factsheet"),
            capacity_kg=capacity_kg,
            step_period_s=step_period_s,
            color=color,
        )
        publish(self.probe, "factsheet", self.topics.unit("factsheet", self.unit), message)
        return message

    def state(
        self,
        position: Cell,
        direction: Direction | None = None,
        status: UnitStatus = "idle",
        *,
        step: int | None = None,
        wait_reason: str | None = None,
        mode: Mode = "coordinated",
        job_id: str | None = None,
        load_kg: float = 0.0,
        sensors: Sensors = ALL_FREE,
        obstacles: Sequence[Cell] = (),
        released: Sequence[Cell] = (),
        goal: Cell | None = None,
        estop: bool = False,
        order_id: str | None = None,
        order_update_id: int = 0,
    ) -> UnitState:
        """`units/<id>/state`; the LEDs follow `direction` (all four when stopped).

        `step` defaults to the state's sequence number, so every state is one step later;
        `order_id` and `order_update_id` acknowledge the newest order the unit has taken.
        """
        header = self.stamp("state")
        message = UnitState(
            header=header,
            step=header.seq if step is None else step,
            position=position,
            direction="-" if direction is None else direction.value,
            status=status,
            wait_reason=wait_reason,
            mode=mode,
            job_id=job_id,
            load_kg=load_kg,
            leds=leds_for(direction, stopped=estop or status == "stopped"),
            sensors=sensors,
            obstacles=list(obstacles),
            released=list(released),
            goal=goal,
            estop=estop,
            order_id=order_id,
            order_update_id=order_update_id,
        )
        publish(self.probe, "state", self.topics.unit("state", self.unit), message)
        return message

    def direction(self, direction: Direction | None) -> bytes:
        """`units/<id>/direction`: the plain-text letter for the device (`-`: no move)."""
        payload = encode_direction(direction)
        publish(self.probe, "direction", self.topics.unit("direction", self.unit), payload)
        return payload

    def follow_orders(self) -> None:
        """Subscribe to this unit's `units/<id>/order`, as the unit does (before `orders`)."""
        self.probe.subscribe(self.topics.unit("order", self.unit), qos=1)

    def orders(self) -> list[Order]:
        """Every order the coordinator sent this unit since `follow_orders`, in order."""
        seen = self.probe.received(self.topics.unit("order", self.unit))
        return [decode(Order, m.payload) for m in seen]


class CoordinatorPeer:
    """Publishes what the coordinator publishes (its headers' sender is `sender`)."""

    def __init__(self, probe: MqttProbe, topics: Topics, sender: str = "coordinator") -> None:
        self.probe = probe
        self.topics = topics
        self.stamp = HeaderStamper(sender)

    def map(self, grid: GridMap, obstacles: Sequence[Cell] = ()) -> FleetMap:
        """`fleet/map`: the static map and the obstacles units have discovered."""
        message = FleetMap(
            header=self.stamp("map"),
            name=grid.name,
            width=grid.width,
            height=grid.height,
            rows=grid.rows(),
            obstacles=list(obstacles),
        )
        publish(self.probe, "map", self.topics.fleet("map"), message)
        return message

    def jobs(self, jobs: Sequence[JobView], done_per_minute: Sequence[int] = ()) -> JobsView:
        """`fleet/jobs`: the queue view of `jobs` (the final ones as finished, latest first)."""
        counts: dict[JobState, int] = dict(Counter(job.state for job in jobs))
        ended = [j for j in jobs if j.state in FINAL_JOB_STATES]
        ended.sort(key=lambda j: -1 if j.done_step is None else j.done_step, reverse=True)
        message = JobsView(
            header=self.stamp("jobs"),
            jobs=[j for j in jobs if j.state not in FINAL_JOB_STATES],
            finished=ended[:FINISHED_LISTED],  # the latest; `counts` counts them all
            counts=counts,
            done_per_minute=list(done_per_minute),
        )
        publish(self.probe, "jobs", self.topics.fleet("jobs"), message)
        return message

    def events(self, events: Sequence[EventEntry]) -> EventsView:
        """`fleet/events`: the recent history in words."""
        message = EventsView(header=self.stamp("events"), events=list(events))
        publish(self.probe, "events", self.topics.fleet("events"), message)
        return message

    def routes(self, routes: Mapping[str, RouteView], step: int = 1) -> Routes:
        """`fleet/routes`: every unit's route for display."""
        message = Routes(header=self.stamp("routes"), step=step, routes=dict(routes))
        publish(self.probe, "routes", self.topics.fleet("routes"), message)
        return message

    def status(
        self,
        state: Liveness = "online",
        *,
        step: int = 0,
        step_period_s: float = 1.0,
        estop: bool = False,
        version: str = "0.1.0",
    ) -> CoordinatorStatus:
        """`coordinator/status`: whether the coordinator runs, its step and the stop it sees."""
        message = CoordinatorStatus(
            header=self.stamp("coordinator"),
            state=state,
            step=step,
            step_period_s=step_period_s,
            estop=estop,
            version=version,
        )
        publish(self.probe, "coordinator", self.topics.fleet("coordinator"), message)
        return message

    def reply(
        self,
        client: str,
        request_id: str,
        accepted: bool,
        reason: str | None = None,
        job_id: str | None = None,
    ) -> Reply:
        """`replies/<client>`: the answer to the request `request_id` of `client`."""
        message = Reply(
            header=self.stamp("reply"),
            request_id=request_id,
            accepted=accepted,
            reason=reason,
            job_id=job_id,
        )
        publish(self.probe, "reply", self.topics.reply(client), message)
        return message

    def error(self, topic: str, reason: str, request_id: str | None = None) -> ErrorReport:
        """`errors`: a message on `topic` refused, and why (with its request id when known).

        Built as every component builds it (`gridfleet.outbound.error_report`, cut to its limits);
        returns the report as it went out.
        """
        payload = error_report(self.stamp("errors"), topic, reason, request_id)
        publish(self.probe, "errors", self.topics.fleet("errors"), payload)
        return decode(ErrorReport, payload)
