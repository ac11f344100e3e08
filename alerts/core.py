"""The alerts core: what the fleet publishes and the time in; alerts raised, cleared, acknowledged out.

Pure (no clock, no MQTT, no HTTP): the shell hands it each message with the monotonic time it
arrived, ticks it, and tells it when the broker connection comes and goes; it returns what to
publish (the retained view `fleet/alerts`, replies, error reports) and the webhook's notices as
bytes. Every rule is a condition about a subject (a unit, a job, the fleet) that must hold for
its threshold before it raises; an alert clears when its condition no longer holds. Timestamps
come from the header stamper's clock, durations from the monotonic `now` the shell passes.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import datetime
from typing import Literal, get_args

from pydantic import BaseModel, ConfigDict

from gridfleet.alerts.settings import AlertSettings
from gridfleet.config import names_owned_id
from gridfleet.errors import ProtocolError
from gridfleet.failures import parse_failure
from gridfleet.outbound import Outbound, error_report
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    TOPICS,
    Connection,
    CoordinatorStatus,
    EnergyView,
    ErrorReport,
    HeaderStamper,
    JobsView,
    Reply,
    Topics,
    UnitState,
    decode,
)
from gridfleet.protocol.codec import reply_address
from gridfleet.protocol.constants import MAX_REQUEST_BYTES, MAX_TEXT
from gridfleet.protocol.messages import (
    CLEARED_ALERTS_LISTED,
    MAX_ACTIVE_ALERTS,
    AckAlert,
    AlertEntry,
    AlertRule,
    AlertSeverity,
    AlertsView,
)
from gridfleet.protocol.stop import STOP_KINDS, StopView, stop_filters
from gridfleet.squares import Cell

RULES: tuple[AlertRule, ...] = get_args(AlertRule)
SEVERITY: dict[AlertRule, AlertSeverity] = {
    "unit_lost": "critical",
    "unit_stuck": "warning",
    "job_queued": "warning",
    "estop": "critical",
    "step_rate_low": "warning",
    "coordinator_down": "critical",
    "broker_down": "critical",
    "handler_failures": "warning",
    "battery_low": "warning",
    "battery_critical": "critical",
    "cannot_reach_charger": "critical",
    "zone_wait": "warning",
}
# Wait codes of a job held up by closed zones (protocol.md §5.3): the `zone_wait` rule's.
ZONE_WAITS = ("zone_closed", "unreachable")
# Plans of the energy view (fleet/energy) that mean the coordinator has a low unit in hand.
IN_HAND = ("to_charger", "queued", "charging")
# A restarted alerts process takes over the alerts in force from the retained view: each stays as
# it was (its id, its acknowledgement) while its condition can still be found again, which takes
# the rule's threshold (its clock starts when the new process first hears the subject) and the
# retained messages' arrival; found again, it is adopted, with no second notice; not, it clears.
ADOPT_SLACK_S = 10.0
# Until the last run's view is read, or this long after the first connect (there was none), this
# run publishes no view of its own: it would replace the retained one before it arrived.
INHERIT_WAIT_S = 2.0
# Roles whose accounts may acknowledge an alert: the people who may change the fleet.
ACK_ROLES = frozenset({"operator", "dashboard"})
STILL = ("waiting", "holding")  # a unit in one of these, on one square, is not getting on
Event = Literal["raised", "cleared", "acknowledged"]
Note = tuple[int, str]
Key = tuple[AlertRule, str | None]  # one condition: its rule and subject
# The webhook's `text` is read by chat tools (Slack, Mattermost), where `<!channel>` pings
# everybody and `<http://…|…>` is a link: what a unit or a press says must not become markup.
CHAT_ESCAPES = {"&": "&amp;", "<": "&lt;", ">": "&gt;"}
CHAT_TEXT_CHARS = 400  # one line for people, however long the reasons in it
# Control characters (terminal escapes, line breaks, bells) and the invisible direction
# overrides and line separators that make a line read other than it is: left out.
_UNSEEN = {*range(0x20), *range(0x7F, 0xA0), 0x2028, 0x2029, *range(0x202A, 0x202F)}
_UNSEEN |= set(range(0x2066, 0x206A))


class Notice(BaseModel):
    """The webhook's JSON body: one raise, clear or acknowledgement (docs/monitoring.md)."""

    # Built on first use, as the protocol's models: building at import loads pydantic's plugin
    # machinery, and with it the socket module (tests/system/test_layers.py).
    model_config = ConfigDict(frozen=True, extra="forbid", defer_build=True)

    event: Event
    at: datetime  # when it happened
    fleet: str  # the topic root: which fleet, where several share a receiver
    text: str  # one line for people (chat): severity, what, and who acknowledged
    alert: AlertEntry


@dataclass
class Effects:
    """What one call asks of the shell."""

    publish: list[Outbound] = field(default_factory=list)
    notices: list[bytes] = field(default_factory=list)  # webhook bodies, in order
    log: list[Note] = field(default_factory=list)


@dataclass
class _Unit:
    """What the rules know of one unit."""

    heard_at: float  # the last state (or `online`) arrived then
    connection: str | None = None
    position: Cell | None = None
    status: str | None = None
    wait_reason: str | None = None
    still_since: float | None = None  # waiting or holding on one square since
    battery_pct: float | None = None  # its charge (None: it reports no energy)
    charging: bool = False


@dataclass
class _Failing:
    """A component's failed handlers, as its reports on `errors` told them."""

    last_at: float  # the latest report arrived then
    topic: str  # the topic of the first of this spell, and its exception's class
    error: str
    count: int = 0  # failures told of since the spell began


class AlertsCore:
    """Rules over the fleet's messages: `on_message`, `tick`, `connected`, `disconnected`."""

    def __init__(
        self,
        topics: Topics,
        settings: AlertSettings,
        stamp: HeaderStamper,
        *,
        nonce: str,
        now: float,
        accounts: Mapping[str, str] | None = None,
    ) -> None:
        self.topics = topics
        self.settings = settings
        self.stamp = stamp
        self.nonce = nonce  # alert ids of one run never meet another run's
        # Account name -> role: who sent an acknowledgement (None: no accounts, the sender is
        # taken as it is: a broker without accounts vouches for nobody).
        self.accounts = accounts
        self.active: dict[Key, AlertEntry] = {}  # in raising order
        self.cleared: list[AlertEntry] = []  # newest first, at most CLEARED_ALERTS_LISTED
        self.raised_total: Counter[str] = Counter()
        self.cleared_total: Counter[str] = Counter()
        self._count = 0
        self._units: dict[str, _Unit] = {}
        self._failing: dict[str, _Failing] = {}  # component kind -> its failures of late
        self._queued: dict[str, tuple[float, str | None]] = {}  # job -> (queued since, why)
        self._zone_waits: dict[str, tuple[float, str | None]] = {}  # job -> (since, why)
        self._stop = StopView()
        self._energy: EnergyView | None = None  # the coordinator's thresholds and plans
        self._since: dict[Key, float] = {}  # an energy condition -> since when it holds
        self._status: CoordinatorStatus | None = None
        self._status_at = now  # no status yet: the coordinator counts as down from the start
        self._online = False  # the broker connection, as the shell reports it
        self._offline_since: float | None = now
        self._adopting: dict[Key, float] = {}  # alerts taken over from the last run -> until when
        self._inheriting = True  # until the last run's view is read (or INHERIT_WAIT_S passed)
        self._inherit_until: float | None = None  # set at the first connect

    # ---- what the shell calls -----------------------------------------------------------

    def subscriptions(self) -> list[tuple[str, int]]:
        """Every filter the rules follow, with its subscription QoS."""
        t = self.topics
        return [
            (t.all_units("connection"), SUBSCRIBE_QOS),
            (t.all_units("state"), SUBSCRIBE_QOS),
            (t.fleet("jobs"), SUBSCRIBE_QOS),
            (t.fleet("coordinator"), SUBSCRIBE_QOS),
            (t.fleet("energy"), SUBSCRIBE_QOS),  # thresholds and plans: battery rules
            *stop_filters(t),
            (t.request("ack_alert"), TOPICS["ack_alert"].qos),
            (t.fleet("alerts"), TOPICS["alerts"].qos),  # the last run's view, to take over
            (t.fleet("errors"), TOPICS["errors"].qos),  # components' failed handlers
        ]

    def connected(self, now: float) -> Effects:
        """The broker session is up (again): the view goes out; silence so far was our own."""
        self._online = True
        self._offline_since = None
        # Nothing could be heard meanwhile: units and the coordinator are judged afresh from now.
        for unit in self._units.values():
            unit.heard_at = max(unit.heard_at, now)
        self._status_at = max(self._status_at, now)
        if self._inherit_until is None:
            self._inherit_until = now + INHERIT_WAIT_S
        return self._evaluate(now, view=True)

    def disconnected(self, now: float) -> Effects:
        """The broker session is lost: only `broker_down` can change until it is back."""
        if self._online:
            self._online = False
            self._offline_since = now
        return self._evaluate(now)

    def tick(self, now: float) -> Effects:
        """Raise what has lasted its threshold, clear what has ended."""
        waited = self._inherit_until is not None and now >= self._inherit_until
        if self._inheriting and waited:
            self._inheriting = False  # no view was retained: nothing to take over
            return self._evaluate(now, view=True)
        return self._evaluate(now)

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        """One message the rules follow; a bad one is reported on `errors` and changes nothing."""
        try:
            kind, ident = self.topics.parse(topic)
        except ProtocolError:
            return Effects()  # not ours to judge
        if kind == "errors":
            return self._on_error_report(payload, now)
        try:
            if kind == "ack_alert":
                return self._on_ack(topic, payload, now)
            if kind == "alerts":
                view = decode(AlertsView, payload, TOPICS["alerts"].max_bytes)
                was = self._inheriting
                self._inherit(view, now)
                return self._evaluate(now, view=was and not self._inheriting)
            self._read(kind, ident, topic, payload, now)
        except ProtocolError as exc:
            return Effects(
                publish=[self._error(topic, str(exc), None)],
                log=[(logging.WARNING, f"refused a message on {topic}: {exc}")],
            )
        return self._evaluate(now)

    @property
    def settled(self) -> bool:
        """The last run's view read (or waited for) and each of its alerts kept or cleared."""
        return not self._inheriting and not self._adopting

    def view(self) -> Outbound:
        """The retained view: the alerts in force, oldest first, and the latest cleared."""
        active = list(self.active.values())[:MAX_ACTIVE_ALERTS]
        view = AlertsView(header=self.stamp("alerts"), active=active, cleared=self.cleared)
        return Outbound.of("alerts", self.topics.fleet("alerts"), view)

    # ---- reading --------------------------------------------------------------------------

    def _inherit(self, view: AlertsView, now: float) -> None:
        """Take over the alerts of the last run's retained view."""
        mine = f"{self.nonce}-"
        if not self._inheriting or any(a.id.startswith(mine) for a in view.active):
            return  # our own view, come back
        self._inheriting = False
        for alert in view.active:
            key = (alert.rule, alert.subject)
            if key not in self.active:
                self.active[key] = alert
                self._adopting[key] = now + self._threshold(alert.rule) + ADOPT_SLACK_S
        known = {a.id for a in self.cleared}
        inherited = [a for a in view.cleared if a.id not in known]
        self.cleared = sorted(
            [*self.cleared, *inherited], key=lambda a: a.cleared_at or a.raised_at, reverse=True
        )[:CLEARED_ALERTS_LISTED]

    def _threshold(self, rule: AlertRule) -> float:
        """How long a condition of `rule` takes to be found, heard from its start."""
        s = self.settings
        seconds = {
            "unit_lost": s.unit_lost_s,
            "unit_stuck": s.unit_stuck_s,
            "job_queued": s.job_queued_s,
            "zone_wait": s.zone_wait_s,
            "coordinator_down": s.coordinator_down_s,
            "battery_low": s.battery_low_s,
            "battery_critical": s.battery_critical_s,
            "cannot_reach_charger": s.cannot_reach_charger_s,
        }.get(rule)
        return seconds or 0.0

    def _read(self, kind: str, ident: str | None, topic: str, payload: bytes, now: float) -> None:
        if kind in ("state", "connection") and ident is not None and not payload:
            self._units.pop(ident, None)  # cleared: a unit removed for good (protocol.md §6.11)
            return
        if kind == "state" and ident is not None:
            self._on_state(ident, decode(UnitState, payload), now)
        elif kind == "connection" and ident is not None:
            state = decode(Connection, payload).state
            unit = self._units.setdefault(ident, _Unit(heard_at=now))
            unit.connection = state
            if state == "online":
                unit.heard_at = now
        elif kind in STOP_KINDS:
            self._stop.apply(kind, ident, topic, payload)
        elif kind == "jobs":
            self._on_jobs(decode(JobsView, payload, TOPICS["jobs"].max_bytes), now)
        elif kind == "energy":
            # Cleared (`gridfleet clean`): no thresholds known, so no battery rule holds.
            self._energy = (
                decode(EnergyView, payload, TOPICS["energy"].max_bytes) if payload else None
            )
        elif kind == "coordinator":
            self._status = decode(CoordinatorStatus, payload)
            self._status_at = now

    def _on_state(self, ident: str, state: UnitState, now: float) -> None:
        unit = self._units.setdefault(ident, _Unit(heard_at=now))
        unit.heard_at = now
        still = state.status in STILL
        if not still or unit.still_since is None or unit.position != state.position:
            unit.still_since = now if still else None
        unit.position = state.position
        unit.status = state.status
        unit.wait_reason = state.wait_reason
        unit.battery_pct = state.battery_pct
        unit.charging = state.charging

    def _on_error_report(self, payload: bytes, now: float) -> Effects:
        """A report on `errors`: a component's failed handler counts (a refusal does not, and a
        bad report is dropped unanswered: an answer on `errors` to `errors` would echo junk)."""
        try:
            report = decode(ErrorReport, payload, TOPICS["errors"].max_bytes)
        except ProtocolError:
            return Effects()
        failure = parse_failure(report.reason)
        if failure is None:
            return Effects()
        failing = self._failing.get(failure.component)
        if failing is None:
            failing = self._failing[failure.component] = _Failing(now, report.topic, failure.error)
        failing.last_at = now
        failing.count += failure.count
        return self._evaluate(now)

    def _on_jobs(self, view: JobsView, now: float) -> None:
        queued = {job.id: job.wait_reason for job in view.jobs if job.state == "queued"}
        self._queued = {
            job: (self._queued[job][0] if job in self._queued else now, why)
            for job, why in queued.items()
        }
        # Waiting on closed zones, queued or under way: counted from its first such wait.
        zoned = {job.id: job.wait_reason for job in view.jobs if job.wait in ZONE_WAITS}
        self._zone_waits = {
            job: (self._zone_waits[job][0] if job in self._zone_waits else now, why)
            for job, why in zoned.items()
        }

    # ---- the rules --------------------------------------------------------------------------

    def _conditions(self, now: float) -> dict[Key, str]:
        """Every condition that holds now and has lasted its threshold, with its words."""
        s = self.settings
        found: dict[Key, str] = {}
        if s.broker_down_s is not None and self._offline_since is not None:
            gone = now - self._offline_since
            if gone > s.broker_down_s:
                found["broker_down", None] = (
                    f"the alerts process has had no broker for {gone:.0f} s"
                )
        window = s.handler_failures_s
        for component, failing in list(self._failing.items()):
            if window is None or now - failing.last_at > window:
                del self._failing[component]  # quiet for the window: the spell is over
            else:
                found["handler_failures", component] = (
                    f"{component} failed handling a message on {failing.topic} "
                    f"({failing.error}); its log has the details"
                )
        if not self._online:
            # Deaf, it cannot judge the rest: what was raised stays, nothing new is raised.
            for key, alert in self.active.items():
                if key[0] != "broker_down":
                    found[key] = alert.text
            return found
        for name, unit in self._units.items():
            silent = now - unit.heard_at
            if unit.connection == "offline":
                continue  # it said goodbye: nobody is to be called
            if s.unit_lost_s is not None and silent > s.unit_lost_s:
                how = "its connection broke" if unit.connection == "broken" else "no state"
                found["unit_lost", name] = (
                    f"unit {name} lost: {how}, nothing heard for {silent:.0f} s"
                )
            elif s.unit_stuck_s is not None and unit.still_since is not None:
                still = now - unit.still_since
                if still > s.unit_stuck_s:
                    where = f"[{unit.position[0]}, {unit.position[1]}]" if unit.position else "?"
                    reason = f": {unit.wait_reason}" if unit.wait_reason else ""
                    found["unit_stuck", name] = (
                        f"unit {name} {unit.status} on {where} for {still:.0f} s{reason}"
                    )
        if s.zone_wait_s is not None:
            for job, (since, why) in self._zone_waits.items():
                waited = now - since
                if waited > s.zone_wait_s:
                    because = f": {why}" if why else ""
                    found["zone_wait", job] = (
                        f"job {job} held up by closed zones for {waited / 60:.1f} min{because}"
                    )
        if s.job_queued_s is not None:
            for job, (since, why) in self._queued.items():
                if s.zone_wait_s is not None and job in self._zone_waits:
                    continue  # told by zone_wait, which says why
                waited = now - since
                if waited > s.job_queued_s:
                    because = f": {why}" if why else ""
                    found["job_queued", job] = (
                        f"job {job} queued for {waited / 60:.1f} min{because}"
                    )
        found.update(self._energy_conditions(now))
        cause = self._stop.cause
        if s.estop and cause is not None and cause.engaged:
            because = f": {cause.reason}" if cause.reason else ""
            found["estop", None] = f"emergency stop engaged by {cause.by}{because}"
        status = self._status
        up = status is not None and status.state == "online"
        if s.coordinator_down_s is not None:
            quiet = now - self._status_at
            if not up and quiet > s.coordinator_down_s:
                said = f"its status says {status.state}" if status else "no status"
                found["coordinator_down", None] = f"coordinator down: {said} for {quiet:.0f} s"
            elif up and quiet > s.coordinator_down_s:
                found["coordinator_down", None] = f"coordinator silent for {quiet:.0f} s"
        if s.step_rate_below is not None and up and status is not None:
            achieved = status.achieved_step_s
            if achieved is not None and status.step_period_s / achieved < s.step_rate_below:
                found["step_rate_low", None] = (
                    f"the fleet steps {1 / achieved:.2f} times a second, "
                    f"{100 * status.step_period_s / achieved:.0f} % of its "
                    f"{1 / status.step_period_s:.2f}"
                )
        return found

    def _energy_conditions(self, now: float) -> dict[Key, str]:
        """The battery rules, against the thresholds and plans of the energy view: each
        condition counted from when it began to hold (what holds no more starts afresh)."""
        s = self.settings
        energy = self._energy
        holding: dict[Key, str] = {}
        if energy is not None:
            t = energy.thresholds
            for name, unit in self._units.items():
                pct = unit.battery_pct
                plan = energy.units.get(name)
                if unit.connection == "offline":
                    continue  # it said goodbye: its last charge is nobody's emergency
                if plan is not None and plan.plan == "stranded":
                    why = f": {plan.reason}" if plan.reason else ""
                    holding["cannot_reach_charger", name] = (
                        f"unit {name} cannot reach any charger{why}"
                    )
                if pct is None or unit.charging:
                    continue
                if pct <= t.critical_pct:
                    holding["battery_critical", name] = (
                        f"unit {name} battery critical: {pct:.0f} % (at or below "
                        f"{t.critical_pct:g} %), not charging"
                    )
                # Low holds on below critical too (both in force): it clears only once the unit
                # charges, the policy has it in hand or it is back at good.
                if pct < t.good_pct and (plan is None or plan.plan not in IN_HAND):
                    holding["battery_low", name] = (
                        f"unit {name} battery low: {pct:.0f} % (below {t.good_pct:g} %), "
                        "neither charging nor on its way to a charger"
                    )
        self._since = {key: self._since.get(key, now) for key in holding}
        found: dict[Key, str] = {}
        for key, text in holding.items():
            threshold = {
                "battery_low": s.battery_low_s,
                "battery_critical": s.battery_critical_s,
                "cannot_reach_charger": s.cannot_reach_charger_s,
            }[key[0]]
            lasted = now - self._since[key]
            if threshold is not None and lasted > threshold:
                found[key] = f"{text} for {lasted:.0f} s"
        return found

    def _evaluate(self, now: float, *, view: bool = False) -> Effects:
        out = Effects()
        found = self._conditions(now)
        at = self.stamp.now()
        for key in [k for k in self._adopting if k in found and self._online]:
            del self._adopting[key]  # the last run's alert holds still: ours now, told once
            out.log.append((logging.INFO, f"alert {self.active[key].id} taken over"))
        waiting = {k for k, until in self._adopting.items() if now < until}
        for key in [k for k in self.active if k not in found and k not in waiting]:
            self._adopting.pop(key, None)
            alert = self.active.pop(key).model_copy(update={"cleared_at": at})
            self.cleared = [alert, *self.cleared][:CLEARED_ALERTS_LISTED]
            self.cleared_total[alert.rule] += 1
            out.notices.append(self._notice("cleared", alert, at))
            out.log.append((logging.INFO, f"alert {alert.id} cleared: {alert.text}"))
        for key, text in found.items():
            if key in self.active:
                continue
            rule, subject = key
            self._count += 1
            alert = AlertEntry(
                id=f"{self.nonce}-{self._count}",
                rule=rule,
                subject=subject,
                severity=SEVERITY[rule],
                # A unit's reason may fill MAX_TEXT alone: the words around it must still fit.
                text=text if len(text) <= MAX_TEXT else text[: MAX_TEXT - 1] + "…",
                raised_at=at,
            )
            self.active[key] = alert
            self.raised_total[rule] += 1
            out.notices.append(self._notice("raised", alert, at))
            out.log.append((logging.WARNING, f"alert {alert.id} raised: {text}"))
        if (view or out.notices) and self._online and not self._inheriting:
            out.publish.append(self.view())
        return out

    # ---- acknowledgements --------------------------------------------------------------------

    def _on_ack(self, topic: str, payload: bytes, now: float) -> Effects:
        request_id, reply_to = reply_address(payload)
        try:
            ack = decode(AckAlert, payload, MAX_REQUEST_BYTES)
            actor = self._actor(ack.header.sender)
        except ProtocolError as exc:
            return self._refuse(topic, str(exc), request_id, reply_to)
        found = self._find(ack.alert_id)
        if found is None:
            reason = f"no alert {ack.alert_id!r}: it is neither active nor among the latest cleared"
            return self._refuse(topic, reason, ack.request_id, ack.reply_to)
        out = Effects()
        if found.acked_by is None:  # acknowledged already: the first one stands, nothing changes
            at = self.stamp.now()
            acked = found.model_copy(update={"acked_by": actor, "acked_at": at})
            self._replace(acked)
            out.notices.append(self._notice("acknowledged", acked, at))
            out.publish.append(self.view())
            out.log.append((logging.INFO, f"alert {acked.id} acknowledged by {actor}"))
        if ack.reply_to is not None:
            out.publish.append(self._reply(ack.reply_to, ack.request_id, True, None))
        return out

    def _actor(self, sender: str) -> str:
        """The account that sent a request: the broker binds its sender to the account (§10)."""
        if self.accounts is None:
            return sender
        owners = [name for name in self.accounts if names_owned_id(name, sender)]
        if not owners:
            raise ProtocolError(f"sender {sender!r} belongs to no account")
        owner = max(owners, key=len)  # the longest name that fits owns it, as at the broker
        role = self.accounts[owner]
        if role not in ACK_ROLES:
            raise ProtocolError(f"account {owner!r} ({role}) may not acknowledge alerts")
        return owner

    def _find(self, alert_id: str) -> AlertEntry | None:
        for alert in (*self.active.values(), *self.cleared):
            if alert.id == alert_id:
                return alert
        return None

    def _replace(self, alert: AlertEntry) -> None:
        for key, old in self.active.items():
            if old.id == alert.id:
                self.active[key] = alert
                return
        self.cleared = [alert if old.id == alert.id else old for old in self.cleared]

    def _refuse(
        self, topic: str, reason: str, request_id: str | None, reply_to: str | None
    ) -> Effects:
        out = Effects(publish=[self._error(topic, reason, request_id)])
        if request_id is not None and reply_to is not None:
            out.publish.append(self._reply(reply_to, request_id, False, reason))
        out.log.append((logging.WARNING, f"refused an acknowledgement: {reason}"))
        return out

    # ---- messages out -------------------------------------------------------------------------

    def _reply(
        self, reply_to: str, request_id: str, accepted: bool, reason: str | None
    ) -> Outbound:
        reply = Reply(
            header=self.stamp("reply"), request_id=request_id, accepted=accepted, reason=reason
        )
        return Outbound.of("reply", self.topics.reply(reply_to), reply)

    def report(self, topic: str, reason: str) -> Outbound:
        """A report on `errors` about a message on `topic` (the shell's failed handlers)."""
        return self._error(topic, reason, None)

    def _error(self, topic: str, reason: str, request_id: str | None) -> Outbound:
        payload = error_report(self.stamp("errors"), topic, reason, request_id)
        return Outbound.of("errors", self.topics.fleet("errors"), payload)

    def _notice(self, event: Event, alert: AlertEntry, at: datetime) -> bytes:
        if event == "raised":
            line = f"[{alert.severity.upper()}] {alert.text}"
        elif event == "cleared":
            line = f"[CLEARED] {alert.text}"
        else:
            line = f"[ACKNOWLEDGED by {alert.acked_by}] {alert.text}"
        # The line is for chat: markup neutralised; the alert itself goes as the view has it.
        text = chat_text(line)
        notice = Notice(event=event, at=at, fleet=self.topics.root, text=text, alert=alert)
        return notice.model_dump_json().encode()


def chat_text(line: str, limit: int = CHAT_TEXT_CHARS) -> str:
    """`line` safe for a chat tool: `&`, `<`, `>` escaped, control characters out, bounded."""
    pieces: list[str] = []
    size = 0
    for char in line:
        if ord(char) in _UNSEEN:
            continue
        piece = CHAT_ESCAPES.get(char, char)
        if size + len(piece) > limit - 1:  # room for the ellipsis; an entity stays whole
            pieces.append("…")
            break
        pieces.append(piece)
        size += len(piece)
    return "".join(pieces)
