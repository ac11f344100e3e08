"""A typed operator for tests: requests with their replies, the emergency stop, what the fleet says.

`OperatorPeer` plays an operator's script (as `gridfleet job` or the dashboard would): each
request (set_goal, submit_job, cancel_job) gets a request id of its own and waits for the reply
with that id on `replies/<name>` (its `send_` form only sends, for a test whose coordinator runs in
its own event loop); it engages and releases the retained `fleet/estop`; and it reads every unit's
states, directions and connections, the coordinator's status, queue view and error reports
(`support.readers.FleetReader`), decoded with the protocol's own decoders. Everything goes
through an `MqttProbe`.
"""

from __future__ import annotations

import itertools
import time
from typing import TypedDict, Unpack

from gridfleet.grid import Cell
from gridfleet.protocol import (
    CancelJob,
    CloseZone,
    ControlUnit,
    EstopSignal,
    HeaderStamper,
    OpenZone,
    Reply,
    SetGoal,
    SubmitJob,
    Topics,
    decode,
    decode_estop,
    encode_estop,
)
from gridfleet.protocol.messages import Request

from support.fleet_peer import publish
from support.probe import MqttProbe
from support.readers import FleetReader
from support.wait import WaitTimeout, wait_for

ASK_S = 20.0  # how long a request waits for its reply, sent again meanwhile
RESEND_S = 2.0  # the first wait before it is sent again; doubled each time (as RETRY_S)


class JobOptions(TypedDict, total=False):
    """A job's optional fields: its priority (default 0) and its id (default: the coordinator's)."""

    priority: int
    job_id: str | None


class OperatorPeer(FleetReader):
    """Sends requests and awaits their replies; engages and releases the stop; reads the fleet.

    It subscribes on creation (its replies, the estop, the coordinator's status, queue view and
    error reports, every unit's state, direction and connection), so whatever arrives afterwards
    is kept by its probe.
    """

    def __init__(self, probe: MqttProbe, topics: Topics, name: str = "operator") -> None:
        self.probe = probe
        self.topics = topics
        self.name = name
        self.stamp = HeaderStamper(name)
        self._ids = itertools.count(1)
        probe.subscribe(topics.reply(name), qos=1)
        probe.subscribe(topics.fleet("estop"), qos=1)
        probe.subscribe(topics.fleet("coordinator"), qos=1)
        probe.subscribe(topics.fleet("jobs"), qos=1)
        probe.subscribe(topics.fleet("errors"), qos=1)
        probe.subscribe(topics.all_units("connection"), qos=1)
        probe.subscribe(topics.all_units("state"), qos=0)  # high rate: QoS 0 (protocol §2)
        probe.subscribe(topics.all_units("direction"), qos=0)

    # -- requests and their replies -------------------------------------------------------------

    def set_goal(self, unit: str, target: Cell | None, *, timeout: float = ASK_S) -> Reply:
        """Send `unit` to `target` (None clears its goal); the coordinator's reply."""
        return self._answer("set_goal", self.send_set_goal(unit, target), timeout)

    def send_set_goal(self, unit: str, target: Cell | None) -> SetGoal:
        """`set_goal` without waiting: the request sent (its `request_id` finds the reply)."""
        request = SetGoal(
            header=self.stamp("set_goal"),
            request_id=self._request_id(),
            reply_to=self.name,
            unit=unit,
            target=target,
        )
        self._send("set_goal", request)
        return request

    def send_control_unit(self, unit: str, command: str) -> ControlUnit:
        """`control_unit` without waiting: the request sent (its `request_id` finds the reply)."""
        request = ControlUnit(
            header=self.stamp("control_unit"),
            request_id=self._request_id(),
            reply_to=self.name,
            unit=unit,
            command=command,  # type: ignore[arg-type]
        )
        self._send("control_unit", request)
        return request

    def submit_job(
        self,
        pickup: Cell,
        dropoff: Cell,
        mass_kg: float,
        *,
        timeout: float = ASK_S,
        **options: Unpack[JobOptions],
    ) -> Reply:
        """Queue a job; the coordinator's reply (its `job_id` names the job when accepted)."""
        request = self.send_submit_job(pickup, dropoff, mass_kg, **options)
        return self._answer("submit_job", request, timeout)

    def send_submit_job(
        self, pickup: Cell, dropoff: Cell, mass_kg: float, **options: Unpack[JobOptions]
    ) -> SubmitJob:
        """`submit_job` without waiting: the request sent (its `request_id` finds the reply)."""
        request = SubmitJob(
            header=self.stamp("submit_job"),
            request_id=self._request_id(),
            reply_to=self.name,
            pickup=pickup,
            dropoff=dropoff,
            mass_kg=mass_kg,
            **options,
        )
        self._send("submit_job", request)
        return request

    def cancel_job(self, job_id: str, *, timeout: float = ASK_S) -> Reply:
        """Delete a queued job or abort an active one; the coordinator's reply."""
        return self._answer("cancel_job", self.send_cancel_job(job_id), timeout)

    def send_cancel_job(self, job_id: str) -> CancelJob:
        """`cancel_job` without waiting: the request sent (its `request_id` finds the reply)."""
        request = CancelJob(
            header=self.stamp("cancel_job"),
            request_id=self._request_id(),
            reply_to=self.name,
            job_id=job_id,
        )
        self._send("cancel_job", request)
        return request

    def close_zone(
        self, name: str, first: Cell, last: Cell, reason: str, *, timeout: float = ASK_S
    ) -> Reply:
        """Close the rectangle `first`..`last` as zone `name`; the coordinator's reply."""
        request = CloseZone(
            header=self.stamp("close_zone"),
            request_id=self._request_id(),
            reply_to=self.name,
            name=name,
            first=first,
            last=last,
            reason=reason,
        )
        self._send("close_zone", request)
        return self._answer("close_zone", request, timeout)

    def open_zone(self, name: str, *, timeout: float = ASK_S) -> Reply:
        """Open the closed zone `name` again; the coordinator's reply."""
        request = OpenZone(
            header=self.stamp("open_zone"),
            request_id=self._request_id(),
            reply_to=self.name,
            name=name,
        )
        self._send("open_zone", request)
        return self._answer("open_zone", request, timeout)

    def raw_request(self, kind: str, payload: bytes) -> None:
        """Send any bytes as a request of `kind` (to see the coordinator refuse them)."""
        publish(self.probe, kind, self.topics.request(kind), payload)

    def replies(self) -> list[Reply]:
        """Every reply on this operator's `replies/<name>`, in the order they arrived."""
        return [decode(Reply, m.payload) for m in self.probe.received(self.topics.reply(self.name))]

    def find_reply(self, request_id: str) -> Reply | None:
        """The reply carrying `request_id`, if it has come (replies to others are passed over)."""
        return next((r for r in self.replies() if r.request_id == request_id), None)

    def reply_to(self, request_id: str, timeout: float = 10.0) -> Reply:
        """The reply carrying `request_id` (waits for it to arrive)."""
        reply = wait_for(
            lambda: self.find_reply(request_id), timeout, what=f"the reply to request {request_id}"
        )
        assert reply is not None
        return reply

    def _answer(self, kind: str, request: Request, timeout: float) -> Reply:
        """The reply to `request` (just sent), sending it again while none comes, as the
        operator's client does (console/operator.py): the coordinator answers a repeat with its
        first answer, and a coordinator whose session broke and came back (CI, once, on a busy
        machine) never saw the first."""
        deadline = time.monotonic() + timeout
        pause = RESEND_S
        while True:
            wait = min(pause, deadline - time.monotonic())
            try:
                return self.reply_to(request.request_id, max(wait, 0.0))
            except WaitTimeout:
                if time.monotonic() >= deadline:
                    raise
            self._send(kind, request)
            pause *= 2

    def _request_id(self) -> str:
        return f"{self.name}-{next(self._ids)}"

    def _send(self, kind: str, request: Request) -> None:
        publish(self.probe, kind, self.topics.request(kind), request)

    # -- the emergency stop ---------------------------------------------------------------------

    def engage(self, reason: str = "", *, by: str | None = None) -> EstopSignal:
        """Engage the retained, latched stop (`by` defaults to this operator's name)."""
        return self._estop(EstopSignal(True, by or self.name, reason))

    def release(self, reason: str = "", *, by: str | None = None) -> EstopSignal:
        """Release the stop: the operator's deliberate act."""
        return self._estop(EstopSignal(False, by or self.name, reason))

    def _estop(self, signal: EstopSignal) -> EstopSignal:
        self.raw_estop(encode_estop(signal))
        return signal

    def raw_estop(self, payload: bytes) -> None:
        """Send any bytes as the retained stop: a malformed one, or b"" to clear the value."""
        publish(self.probe, "estop", self.topics.fleet("estop"), payload)

    def estop_signals(self) -> list[EstopSignal]:
        """Every value seen on `fleet/estop` (the retained one first, when there was one)."""
        return [decode_estop(m.payload) for m in self.probe.received(self.topics.fleet("estop"))]
