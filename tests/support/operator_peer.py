"""A typed operator for tests: requests with their replies, the emergency stop, what units publish.

`OperatorPeer` plays an operator's script (as `gridfleet job` or the dashboard would): each
request (set_goal, submit_job, cancel_job) gets a request id of its own and waits for the reply
with that id on `replies/<name>`; it engages and releases the retained `fleet/estop`; and it reads
every unit's states and directions and the coordinator's status, decoded with the protocol's own
decoders (`gridfleet.protocol.decode`, `decode_direction`, `decode_estop`). Everything goes
through an `MqttProbe`.
"""

from __future__ import annotations

import itertools

from gridfleet.grid import Cell, Direction
from gridfleet.protocol import (
    CancelJob,
    CoordinatorStatus,
    EstopSignal,
    HeaderStamper,
    Reply,
    SetGoal,
    SubmitJob,
    Topics,
    UnitState,
    decode,
    decode_direction,
    decode_estop,
    encode_estop,
)

from support.fleet_peer import publish
from support.probe import MqttProbe
from support.wait import wait_for


class OperatorPeer:
    """Sends requests and awaits their replies; engages and releases the stop; reads the fleet.

    It subscribes on creation (its replies, the estop, the coordinator's status, every unit's
    state and direction), so whatever arrives afterwards is kept by its probe.
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
        probe.subscribe(topics.all_units("state"), qos=0)  # high rate: QoS 0 (protocol §2)
        probe.subscribe(topics.all_units("direction"), qos=0)

    # -- requests and their replies -------------------------------------------------------------

    def set_goal(self, unit: str, target: Cell | None, *, timeout: float = 10.0) -> Reply:
        """Send `unit` to `target` (None clears its goal); the coordinator's reply."""
        request = SetGoal(
            header=self.stamp("set_goal"),
            request_id=self._request_id(),
            reply_to=self.name,
            unit=unit,
            target=target,
        )
        publish(self.probe, "set_goal", self.topics.request("set_goal"), request)
        return self.reply_to(request.request_id, timeout)

    def submit_job(
        self,
        pickup: Cell,
        dropoff: Cell,
        mass_kg: float,
        *,
        priority: int = 0,
        job_id: str | None = None,
        timeout: float = 10.0,
    ) -> Reply:
        """Queue a job; the coordinator's reply (its `job_id` names the job when accepted)."""
        request = SubmitJob(
            header=self.stamp("submit_job"),
            request_id=self._request_id(),
            reply_to=self.name,
            pickup=pickup,
            dropoff=dropoff,
            mass_kg=mass_kg,
            priority=priority,
            job_id=job_id,
        )
        publish(self.probe, "submit_job", self.topics.request("submit_job"), request)
        return self.reply_to(request.request_id, timeout)

    def cancel_job(self, job_id: str, *, timeout: float = 10.0) -> Reply:
        """Delete a queued job or abort an active one; the coordinator's reply."""
        request = CancelJob(
            header=self.stamp("cancel_job"),
            request_id=self._request_id(),
            reply_to=self.name,
            job_id=job_id,
        )
        publish(self.probe, "cancel_job", self.topics.request("cancel_job"), request)
        return self.reply_to(request.request_id, timeout)

    def replies(self) -> list[Reply]:
        """Every reply on this operator's `replies/<name>`, in the order they arrived."""
        return [decode(Reply, m.payload) for m in self.probe.received(self.topics.reply(self.name))]

    def reply_to(self, request_id: str, timeout: float = 10.0) -> Reply:
        """The reply carrying `request_id` (replies to other requests are passed over)."""

        def matching() -> Reply | None:
            return next((r for r in self.replies() if r.request_id == request_id), None)

        reply = wait_for(matching, timeout, what=f"the reply to request {request_id}")
        assert reply is not None
        return reply

    def _request_id(self) -> str:
        return f"{self.name}-{next(self._ids)}"

    # -- the emergency stop ---------------------------------------------------------------------

    def engage(self, reason: str = "", *, by: str | None = None) -> EstopSignal:
        """Engage the retained, latched stop (`by` defaults to this operator's name)."""
        return self._estop(EstopSignal(True, by or self.name, reason))

    def release(self, reason: str = "", *, by: str | None = None) -> EstopSignal:
        """Release the stop: the operator's deliberate act."""
        return self._estop(EstopSignal(False, by or self.name, reason))

    def _estop(self, signal: EstopSignal) -> EstopSignal:
        publish(self.probe, "estop", self.topics.fleet("estop"), encode_estop(signal))
        return signal

    def estop_signals(self) -> list[EstopSignal]:
        """Every value seen on `fleet/estop` (the retained one first, when there was one)."""
        return [decode_estop(m.payload) for m in self.probe.received(self.topics.fleet("estop"))]

    # -- what the units and the coordinator publish ---------------------------------------------

    def states(self, unit: str) -> list[UnitState]:
        """Every state of `unit` seen so far, in the order it was published."""
        return [
            decode(UnitState, m.payload)
            for m in self.probe.received(self.topics.unit("state", unit))
        ]

    def last_state(self, unit: str) -> UnitState | None:
        """The newest state of `unit`, if any."""
        seen = self.probe.received(self.topics.unit("state", unit))
        return decode(UnitState, seen[-1].payload) if seen else None

    def directions(self, unit: str) -> list[Direction | None]:
        """Every direction `unit` published for its device (None: no move), in order."""
        return [
            decode_direction(m.payload)
            for m in self.probe.received(self.topics.unit("direction", unit))
        ]

    def coordinator_status(self) -> CoordinatorStatus | None:
        """The coordinator's newest status, if any."""
        seen = self.probe.received(self.topics.fleet("coordinator"))
        return decode(CoordinatorStatus, seen[-1].payload) if seen else None
