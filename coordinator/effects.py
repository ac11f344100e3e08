"""The coordinator's outbound side: Effects, everything one input asks of the shell, and the
messages they carry, stamped and addressed, with the QoS and retain flag protocol.md gives them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

from gridfleet import __version__
from gridfleet.coordinator.answers import Answer
from gridfleet.coordinator.audit import AuditNews
from gridfleet.coordinator.jobs import Job, JobBook
from gridfleet.coordinator.orders import OrderPlan
from gridfleet.coordinator.records import Entry, RecordKind, RecordQuery
from gridfleet.coordinator.removals import Removal
from gridfleet.coordinator.requests import Outcome
from gridfleet.coordinator.world import World
from gridfleet.coordinator.zones import ZoneChange
from gridfleet.outbound import Outbound, error_report
from gridfleet.protocol import (
    CoordinatorStatus,
    EventEntry,
    HeaderStamper,
    JobHistoryPage,
    Order,
    Reply,
    Routes,
    RouteView,
    Topics,
)
from gridfleet.protocol.messages import AuditPage, ChargeEntry

Status = Literal["online", "offline", "broken"]  # the coordinator's, as on the wire


@dataclass(frozen=True)
class Effects:
    """What the shell does for one input: publish, persist, and when to come back."""

    publish: tuple[Outbound, ...] = ()  # in this order
    persist: tuple[Job, ...] = ()  # jobs changed: store them before publishing
    answered: tuple[Answer, ...] = ()  # answers to new requests: store them with the jobs
    events: tuple[EventEntry, ...] = ()  # new entries of the history: store them
    charges: tuple[ChargeEntry, ...] = ()  # charges started and ended: to the job history store
    controls: tuple[tuple[str, str | None], ...] = ()  # operators' controls changed (None: lifted)
    # Units removed for good, or (None) forgotten as removed once they rejoined: store them.
    removals: tuple[tuple[str, Removal | None], ...] = ()
    zones: tuple[ZoneChange, ...] = ()  # zones closed (to store) or (None) opened: store them
    records: tuple[RecordQuery, ...] = ()  # checked queries: answer each from its store
    audit: AuditNews = field(default_factory=AuditNews)  # operators' acts, stop payloads seen
    awaiting: frozenset[str] = frozenset()  # units yet to acknowledge the last step's orders
    acks_until: float | None = None  # (a step) the next step waits for `awaiting` until then
    views_at: float | None = None  # call `views_due` at this time (end of a batch period)
    log: tuple[tuple[int, str], ...] = ()  # (logging level, line) for the operator's log


class Messages:
    """Builds each outbound message of the coordinator as an Outbound."""

    def __init__(self, topics: Topics, stamp: HeaderStamper) -> None:
        self.topics = topics
        self.stamp = stamp

    def order(self, unit_id: str, plan: OrderPlan) -> Outbound:
        """An order (or halt order) for one unit."""
        order = Order(
            header=self.stamp("order"),
            order_id=plan.order_id,
            update_id=plan.update_id,
            step=plan.step,
            released=plan.released,
            planned=plan.planned,
            target=plan.target,
            action=plan.action,
            charge=plan.charge,
        )
        return Outbound.of("order", self.topics.unit("order", unit_id), order)

    def routes(self, step: int, routes: dict[str, RouteView]) -> Outbound:
        """The routes view of one step."""
        view = Routes(header=self.stamp("routes"), step=step, routes=routes)
        return Outbound.of("routes", self.topics.fleet("routes"), view)

    def reply(self, reply_to: str, request_id: str, outcome: Outcome) -> Outbound:
        """The answer to a request, to its sender."""
        reply = Reply(
            header=self.stamp("reply"),
            request_id=request_id,
            accepted=outcome.accepted,
            reason=outcome.reason,
            job_id=outcome.job_id,
            code=None if outcome.accepted else outcome.code,
        )
        return Outbound.of("reply", self.topics.reply(reply_to), reply)

    def page(
        self,
        kind: RecordKind,
        reply_to: str,
        request_id: str,
        entries: Sequence[Entry] = (),
        next_cursor: str | None = None,
        refused: str | None = None,
    ) -> Outbound:
        """A page of the record `kind` (or why not) for request `request_id`, to `reply_to`."""
        page_kind, cls, topic = (
            ("audit_reply", AuditPage, self.topics.audit_reply(reply_to))
            if kind == "audit"
            else ("history_reply", JobHistoryPage, self.topics.history_reply(reply_to))
        )
        # Validated as a page of its kind: an entry of the other record would be refused here.
        # Charges (a history query of kind "charges") go in the page's `charges`.
        charges = [e for e in entries if isinstance(e, ChargeEntry)]
        body = {
            "header": self.stamp(page_kind),
            "request_id": request_id,
            "accepted": refused is None,
            "reason": refused,
            "entries": [e for e in entries if not isinstance(e, ChargeEntry)],
            "next_cursor": next_cursor,
        }
        if charges:
            body["charges"] = charges
        page = cls.model_validate(body)
        return Outbound.of(page_kind, topic, page)

    def error(self, topic: str, reason: str, request_id: str | None) -> Outbound:
        """A report on `errors` about a message refused on `topic`."""
        payload = error_report(self.stamp("errors"), topic, reason, request_id)
        return Outbound.of("errors", self.topics.fleet("errors"), payload)

    def status(
        self,
        state: Status,
        step: int,
        step_period_s: float,
        estop: bool,
        achieved_step_s: float | None = None,
    ) -> Outbound:
        """The coordinator's retained status."""
        status = CoordinatorStatus(
            header=self.stamp("coordinator"),
            state=state,
            step=step,
            step_period_s=step_period_s,
            estop=estop,
            version=__version__,
            achieved_step_s=achieved_step_s,
        )
        return Outbound.of("coordinator", self.topics.fleet("coordinator"), status)

    def fleet_map(self, world: World) -> Outbound:
        """The retained map with every discovered obstacle."""
        return Outbound.of("map", self.topics.fleet("map"), world.fleet_map(self.stamp("map")))

    def jobs(self, book: JobBook, step_no: int, step_period_s: float) -> Outbound:
        """The retained queue view at step `step_no`."""
        view = book.view(self.stamp("jobs"), step_no, step_period_s)
        return Outbound.of("jobs", self.topics.fleet("jobs"), view)
