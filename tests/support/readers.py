"""Reading the fleet's topics back: what a test peer's probe received, decoded by the protocol.

`FleetReader` is the one set of readers the typed peers share (`OperatorPeer`, `DispatchPeer`):
every unit's states, directions and connections, the error reports, the coordinator's status and
its queue view, each decoded with the protocol's own decoders. It reads what its probe kept; the
peer that uses it subscribes to the topics it reads.
"""

from __future__ import annotations

from gridfleet.grid import Direction
from gridfleet.protocol import (
    Connection,
    CoordinatorStatus,
    ErrorReport,
    JobsView,
    JobView,
    Leds,
    Topics,
    UnitState,
    decode,
    decode_direction,
)
from gridfleet.protocol.constants import MAX_VIEW_BYTES
from gridfleet.protocol.messages import FINAL_JOB_STATES

from support.fleet_peer import leds_for
from support.probe import MqttProbe


class FleetReader:
    """Decoded views of what `probe` received under `topics`, oldest first."""

    probe: MqttProbe
    topics: Topics

    # -- the units ------------------------------------------------------------------------------

    def states(self, unit: str) -> list[UnitState]:
        """Every state of `unit` seen so far, in the order it was published."""
        seen = self.probe.received(self.topics.unit("state", unit))
        return [decode(UnitState, m.payload) for m in seen]

    def last_state(self, unit: str) -> UnitState | None:
        """The newest state of `unit`, if any."""
        seen = self.probe.received(self.topics.unit("state", unit))
        return decode(UnitState, seen[-1].payload) if seen else None

    def directions(self, unit: str) -> list[Direction | None]:
        """Every direction `unit` published for its device (None: no move), in order."""
        seen = self.probe.received(self.topics.unit("direction", unit))
        return [decode_direction(m.payload) for m in seen]

    def display(self, unit: str, since: float = 0.0) -> list[tuple[UnitState | None, Leds]]:
        """What `unit`'s display showed, in order: each state with its LEDs, each direction.

        The display follows the `direction` topic (the device's feed), which names an order's
        first move at once, between two steps, and each state's LEDs (protocol §4.3, §4.6).
        Messages are taken in their order of arrival here (one connection: the unit's order),
        from monotonic time `since` on; a direction message comes as (None, its LEDs).
        """
        seen = [
            *self.probe.received(self.topics.unit("state", unit)),
            *self.probe.received(self.topics.unit("direction", unit)),
        ]
        shown: list[tuple[UnitState | None, Leds]] = []
        for m in sorted(seen, key=lambda m: m.at):
            if m.at < since:
                continue
            if m.topic.endswith("/direction"):
                shown.append((None, leds_for(decode_direction(m.payload))))
            else:
                state = decode(UnitState, m.payload)
                shown.append((state, state.leds))
        return shown

    def connections(self, unit: str) -> list[str]:
        """What `unit`'s connection topic said (`online`, `offline`, `broken`: its last will).

        An empty payload (a retained value cleared) says nothing and is passed over.
        """
        seen = self.probe.received(self.topics.unit("connection", unit))
        return [decode(Connection, m.payload).state for m in seen if m.payload]

    # -- the coordinator ------------------------------------------------------------------------

    def errors(self) -> list[ErrorReport]:
        """Every report seen on `errors`."""
        seen = self.probe.received(self.topics.fleet("errors"))
        return [decode(ErrorReport, m.payload) for m in seen]

    def coordinator_status(self) -> CoordinatorStatus | None:
        """The coordinator's newest status, if any."""
        seen = self.probe.received(self.topics.fleet("coordinator"))
        return decode(CoordinatorStatus, seen[-1].payload) if seen else None

    def job_views(self) -> list[JobsView]:
        """Every queue view (`fleet/jobs`) seen so far."""
        seen = self.probe.received(self.topics.fleet("jobs"))
        return [decode(JobsView, m.payload, MAX_VIEW_BYTES) for m in seen]

    def listed_jobs(self) -> dict[str, JobView]:
        """Every job the queue views listed, as the newest view to list it did, by job id.

        A view lists only the latest finished jobs (protocol.md §5.3): one that finished earlier
        is known from the views before.
        """
        jobs: dict[str, JobView] = {}
        for view in self.job_views():
            jobs.update((j.id, j) for j in view.listed())
        return jobs

    def job_state(self, job_id: str) -> str | None:
        """The job's state as the queue views last listed it (None: never listed)."""
        job = self.listed_jobs().get(job_id)
        return None if job is None else job.state

    def all_final(self, job_ids: list[str]) -> bool:
        """Every job of `job_ids` has been listed as final."""
        jobs = self.listed_jobs()
        return all(i in jobs and jobs[i].state in FINAL_JOB_STATES for i in job_ids)
