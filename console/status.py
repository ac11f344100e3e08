"""`gridfleet status`: the fleet at a glance in a terminal, from the broker's retained topics.

The stop (latched or pressed, by whom), the coordinator (online or not, its step), every unit
(connection, position, status, job, load, battery, why it waits), the chargers, the closed zones
and the jobs (counts per state, the ones not final listed). `--once` prints it once; otherwise it is drawn again every second.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import math
import sys
import time
import uuid
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TextIO, get_args

import aiomqtt

from gridfleet.bus import reach_first
from gridfleet.endpoint import payload_of
from gridfleet.errors import ConfigError, GridfleetError, ProtocolError
from gridfleet.options import add_common, broker_url
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    TOPICS,
    Connection,
    CoordinatorStatus,
    EnergyView,
    EstopSignal,
    Factsheet,
    JobsView,
    Routes,
    StopView,
    Topics,
    UnitState,
    VehicleCondition,
    ZonesView,
    decode,
)
from gridfleet.protocol.messages import FINAL_JOB_STATES, JobState, UnitEnergy
from gridfleet.protocol.stop import LATCH, STOP_KINDS, stop_filters
from gridfleet.tasks import cancel_and_wait, stop_on_signals, until_stopped

log = logging.getLogger("gridfleet.status")
WAIT_S = 10.0
SETTLE_S = 0.2  # after the coordinator's status, for a broker slower to replay the rest
REDRAW_S = 1.0
MAX_JOBS = 20  # jobs not final listed by name; the rest are counted
CLEAR = "\x1b[H\x1b[2J"  # ANSI: cursor home, clear the screen


@dataclass
class FleetStatus:
    """What the retained topics say about the fleet; `apply` one message at a time."""

    stop: StopView = field(default_factory=StopView)
    coordinator: CoordinatorStatus | None = None
    connections: dict[str, str] = field(default_factory=dict)  # unit -> online/offline/broken
    states: dict[str, UnitState] = field(default_factory=dict)
    controls: dict[str, str] = field(default_factory=dict)  # unit -> an operator's control of it
    notes: dict[str, str] = field(
        default_factory=dict
    )  # unit -> why a closed zone moves or holds it
    models: dict[str, str] = field(default_factory=dict)  # unit -> its factsheet's model
    # unit -> a VDA 5050 vehicle's own battery and errors (protocol.md §4.7)
    vehicles: dict[str, VehicleCondition] = field(default_factory=dict)
    jobs: JobsView | None = None
    energy: EnergyView | None = None  # the energy policy's view: chargers, whom it moves
    zones: ZonesView | None = None  # the zones closed (protocol.md §5.11)

    def apply(self, kind: str, source: str | None, topic: str, payload: bytes) -> None:
        """Read one message; a bad one raises ProtocolError and changes nothing."""
        cleared = not payload  # an empty retained message clears the topic (`gridfleet clean`)
        if kind in STOP_KINDS:
            if kind == LATCH and cleared:
                self.stop.latch = None
            else:
                self.stop.apply(kind, source, topic, payload)
        elif kind == "coordinator":
            self.coordinator = None if cleared else decode(CoordinatorStatus, payload)
        elif kind == "jobs":
            self.jobs = None if cleared else decode(JobsView, payload, TOPICS["jobs"].max_bytes)
        elif kind == "energy":
            self.energy = (
                None if cleared else decode(EnergyView, payload, TOPICS["energy"].max_bytes)
            )
        elif kind == "zones":
            self.zones = None if cleared else decode(ZonesView, payload, TOPICS["zones"].max_bytes)
        elif kind == "routes" and not cleared:
            routes = decode(Routes, payload, TOPICS["routes"].max_bytes).routes
            self.controls = {u: r.control for u, r in routes.items() if r.control is not None}
            self.notes = {u: r.note for u, r in routes.items() if r.note is not None}
        elif kind == "connection" and source is not None:
            if cleared:
                self.connections.pop(source, None)
            else:
                self.connections[source] = decode(Connection, payload).state
        elif kind == "state" and source is not None:
            if cleared:
                self.states.pop(source, None)
            else:
                self.states[source] = decode(UnitState, payload)
        elif kind == "factsheet" and source is not None:
            if cleared:
                self.models.pop(source, None)
            else:
                self.models[source] = decode(Factsheet, payload).model
        elif kind == "vehicle" and source is not None:
            if cleared:
                self.vehicles.pop(source, None)
            else:
                self.vehicles[source] = decode(VehicleCondition, payload)


def _signal(signal: EstopSignal) -> str:
    return signal.by + (f" ({signal.reason})" if signal.reason else "")


def stop_line(fleet: FleetStatus) -> str:
    """`stop: clear`, or who holds the fleet stopped and why."""
    stop = fleet.stop
    presses = ", ".join(_signal(p) for p in sorted(stop.presses.values(), key=lambda p: p.by))
    if stop.latch is not None and stop.latch.engaged:
        return f"stop: ENGAGED, latched by {_signal(stop.latch)}" + (
            f"; pressed by {presses}" if presses else ""
        )
    if presses:
        return f"stop: ENGAGED, pressed by {presses}"
    status = fleet.coordinator
    if status is not None and status.state == "online" and status.estop:
        return "stop: ENGAGED (so says the coordinator; its latch is not on the broker yet)"
    return "stop: clear"


def coordinator_line(status: CoordinatorStatus | None) -> str:
    """Whether the coordinator runs, and at which step and pace."""
    if status is None:
        return "coordinator: no status on the broker (has one ever run under this root?)"
    if status.state == "broken":
        return "coordinator: broken (gone without saying goodbye)"
    if status.state == "offline":
        return f"coordinator: offline (stopped at step {status.step})"
    pace = f"a step every {status.step_period_s:g} s"
    if status.achieved_step_s is not None:
        pace += f", achieved {status.achieved_step_s:.2f} s"
    return f"coordinator: online, step {status.step}, {pace}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]], indent: str = "  ") -> list[str]:
    """Columns padded to their widest cell, the last one left as it is."""
    widths = [max(len(r[i]) for r in (header, *rows)) for i in range(len(header) - 1)]
    return [
        (
            indent + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=False)) + "  " + r[-1]
        ).rstrip()
        for r in (header, *rows)
    ]


PLAN_WORDS = {
    "to_charger": "to charger",
    "queued": "waiting for charger",
    "charging": "charging at",
}


def plan_words(plan: UnitEnergy) -> str:
    """What the energy policy does with a unit: its plan and charger ("to charger C1",
    "stranded"), then the coordinator's reason (alone when it names them already)."""
    if plan.plan == "stranded":
        head = "stranded"
    elif plan.charger is None:
        head = "waiting for a charger" if plan.plan == "queued" else PLAN_WORDS[plan.plan]
    else:
        head = f"{PLAN_WORDS[plan.plan]} {plan.charger}"
    reason = plan.reason
    if not reason:
        return "stranded: it cannot reach a charger" if plan.plan == "stranded" else head
    # A reason that names the charger or the plan already says it all.
    named = plan.charger is not None and plan.charger in reason
    return reason if named or reason.startswith(head.split()[0]) else f"{head}: {reason}"


def battery_cell(state: UnitState | None) -> str:
    """ "62 %", "62 % charging", or "-" for a unit that reports no energy."""
    if state is None or state.battery_pct is None:
        return "-"
    return f"{state.battery_pct:.0f} %" + (" charging" if state.charging else "")


def unit_lines(fleet: FleetStatus) -> list[str]:
    """One line per unit: connection, position, status, job, load, battery (when any unit
    reports one), why it waits and what the energy policy does with it."""
    units = sorted(set(fleet.connections) | set(fleet.states) | set(fleet.vehicles))
    if not units:
        return ["units: none on the broker"]
    online = sum(1 for u in units if fleet.connections.get(u) == "online")
    batteries = any(s.battery_pct is not None for s in fleet.states.values())
    plans = {} if fleet.energy is None else fleet.energy.units
    rows = []
    for unit in units:
        state = fleet.states.get(unit)
        control = fleet.controls.get(unit)
        status: str = "-" if state is None else state.status
        if control is not None:
            status += f", {control.replace('_', ' ')}"
        link = fleet.connections.get(unit, "-")
        vda = fleet.models.get(unit, "").removeprefix("vda5050-")
        if vda != fleet.models.get(unit, ""):
            link += f" (VDA 5050 {vda})"  # a vehicle the adapter carries
        waits = "" if state is None or state.wait_reason is None else state.wait_reason
        own = fleet.vehicles.get(unit)
        if own is not None:
            if own.battery_pct is not None:
                charging = " charging" if own.charging else ""
                link += f", battery {own.battery_pct:.0f} %{charging}"
            if own.errors:  # what the vehicle itself says is wrong, after why it waits
                says = "vehicle: " + "; ".join(own.errors)
                waits = f"{waits}; {says}" if waits else says
        note = fleet.notes.get(unit)  # leaving a closed zone, waiting outside one
        if note and note not in waits:
            waits = f"{waits}; {note}" if waits else note
        plan = plans.get(unit)
        said = "" if plan is None else plan_words(plan)  # to a charger, queued, stranded...
        if said and said not in waits:
            waits = f"{waits}; {said}" if waits else said
        cells = [
            unit,
            link,
            "-" if state is None else f"{state.position.x},{state.position.y}",
            status,
            "-" if state is None or state.job_id is None else state.job_id,
            "-" if state is None else f"{state.load_kg:g}",
        ]
        if batteries:
            cells.append(battery_cell(state))
        rows.append((*cells, waits))
    header = ["unit", "connection", "square", "status", "job", "load kg"]
    if batteries:
        header.append("battery")
    return [f"units: {len(units)}, {online} online", *_table((*header, "waiting for"), rows)]


def charger_lines(fleet: FleetStatus) -> list[str]:
    """The chargers (from the energy view): who is on each or on its way, who waits."""
    energy = fleet.energy
    if energy is None or not energy.chargers:
        return []
    rows = []
    for charger in energy.chargers:
        state = None if charger.unit is None else fleet.states.get(charger.unit)
        if charger.unit is None:
            who = "free"
        elif state is not None and state.charging:
            who = f"{charger.unit} charging"
        else:
            who = f"{charger.unit} on its way"
        square = f"{charger.square.x},{charger.square.y}"
        rows.append((charger.name, square, who, ", ".join(charger.queue) or "-"))
    t = energy.thresholds
    levels = (
        f"critical {t.critical_pct:g} %, good {t.good_pct:g} %, sufficient "
        f"{t.sufficient_pct:g} %, full {t.full_pct:g} %"
    )
    return [
        f"chargers: {len(rows)} ({levels})",
        *_table(("charger", "square", "unit", "queue"), rows),
    ]


def zone_lines(zones: ZonesView | None) -> list[str]:
    """The closed zones (none closed: no lines): each one's corners, why, who closed it."""
    if zones is None or not zones.zones:
        return []
    rows = [
        (
            z.name,
            f"{z.first.x},{z.first.y} to {z.last.x},{z.last.y}",
            z.closed_by or "-",
            z.reason,
        )
        for z in zones.zones
    ]
    return [f"zones closed: {len(rows)}", *_table(("zone", "squares", "closed by", "why"), rows)]


def job_lines(jobs: JobsView | None, most: int = MAX_JOBS) -> list[str]:
    """The count of jobs per state, then the jobs that are not final (at most `most` of them)."""
    if jobs is None:
        return ["jobs: no job queue on the broker"]
    # The counts cover every job ever; a view without them is counted from what it lists.
    counts = jobs.counts or Counter(j.state for j in jobs.listed())
    if not counts:
        return ["jobs: none"]
    lines = ["jobs: " + ", ".join(f"{counts[s]} {s}" for s in get_args(JobState) if counts.get(s))]
    active = [j for j in jobs.jobs if j.state not in FINAL_JOB_STATES]
    rows = [(j.id, j.state, j.unit or "-", j.wait_reason or "") for j in active[:most]]
    if rows:
        lines += _table(("job", "state", "unit", "waiting for"), rows)
    if len(active) > most:
        lines.append(f"  ... and {len(active) - most} more not final")
    return lines


def render(fleet: FleetStatus, most_jobs: int = MAX_JOBS) -> list[str]:
    """The whole view as lines of text: the stop, the coordinator, the units, the chargers (when
    the coordinator has any), the closed zones (when any is), the jobs."""
    chargers = charger_lines(fleet)
    zones = zone_lines(fleet.zones)
    return [
        stop_line(fleet),
        coordinator_line(fleet.coordinator),
        "",
        *unit_lines(fleet),
        *(["", *chargers] if chargers else []),
        *(["", *zones] if zones else []),
        "",
        *job_lines(fleet.jobs, most_jobs),
    ]


class StatusReader:
    """Follows the retained topics of one root into a FleetStatus."""

    def __init__(self, client: aiomqtt.Client, topics: Topics) -> None:
        self.client = client
        self.topics = topics
        self.fleet = FleetStatus()
        self.coordinator_heard = asyncio.Event()

    async def start(self) -> None:
        """Subscribe; the coordinator's status last, so that its arrival marks the rest's.

        A broker sends a subscription's retained messages before it handles the next one.
        """
        t = self.topics
        for topic, qos in [
            *stop_filters(t),
            (t.all_units("connection"), SUBSCRIBE_QOS),
            (t.all_units("state"), SUBSCRIBE_QOS),
            (t.all_units("factsheet"), SUBSCRIBE_QOS),
            (t.all_units("vehicle"), SUBSCRIBE_QOS),
            (t.fleet("jobs"), SUBSCRIBE_QOS),
            (t.fleet("routes"), SUBSCRIBE_QOS),
            (t.fleet("energy"), SUBSCRIBE_QOS),
            (t.fleet("zones"), SUBSCRIBE_QOS),
            (t.fleet("coordinator"), SUBSCRIBE_QOS),
        ]:
            await self.client.subscribe(topic, qos=qos)

    async def listen(self) -> None:
        """Apply messages until the client disconnects."""
        async for message in self.client.messages:
            topic = str(message.topic)
            try:
                kind, source = self.topics.parse(topic)
                self.fleet.apply(kind, source, topic, payload_of(message))
            except ProtocolError as exc:
                log.warning("ignored a bad message on %s: %s", topic, exc)
                continue
            if kind == "coordinator":
                self.coordinator_heard.set()


async def show(url: str, root: str, once: bool, timeout: float, out: TextIO) -> int:
    """Print the fleet's status once (after the coordinator's status) or every second."""
    topics = Topics(root)
    async with reach_first(url, f"status-{uuid.uuid4().hex[:6]}") as reached:
        where = str(reached)  # the broker of a list it got on, and those that did not answer
        reader = StatusReader(reached.client, topics)
        await reader.start()
        listener = asyncio.create_task(reader.listen())
        try:
            if once:
                try:
                    await asyncio.wait_for(reader.coordinator_heard.wait(), timeout)
                except TimeoutError:
                    raise GridfleetError(
                        f"nothing from the coordinator on {where} under root {root!r} within "
                        f"{timeout:g} s: is it running?"
                    ) from None
                await asyncio.sleep(SETTLE_S)
                print("\n".join([f"broker: {where}", *render(reader.fleet)]), file=out)
                return 0
            with contextlib.suppress(TimeoutError):  # the first drawing waits for it a little
                await asyncio.wait_for(reader.coordinator_heard.wait(), REDRAW_S)
            while True:
                title = f"gridfleet status: {where}, root {root!r}, {time.strftime('%H:%M:%S')}"
                lines = [title, "(Ctrl-C to quit)", "", *render(reader.fleet)]
                print(CLEAR + "\n".join(lines), file=out, flush=True)
                await asyncio.sleep(REDRAW_S)
        finally:
            await cancel_and_wait(listener)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet status`."""
    add_common(parser)
    parser.add_argument(
        "--once",
        action="store_true",
        help="print it once and exit (2 when nothing comes from the coordinator within --timeout)",
    )
    parser.add_argument(
        "--timeout",
        type=float,
        default=WAIT_S,
        metavar="S",
        help=f"--once: seconds to wait for the coordinator's status (default {WAIT_S:g})",
    )


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet status`."""
    if not 0 < args.timeout < math.inf:
        raise ConfigError(f"--timeout {args.timeout:g}: give a positive number of seconds")
    try:
        root = Topics(args.root).root
    except ProtocolError as exc:
        raise ConfigError(f"--root: {exc}") from None
    url = broker_url(args, "operator")

    async def main() -> int:
        # Ctrl-C, SIGTERM or a closed terminal is how the view is left; handled here, not by
        # Python's default, which a shell's background job (SIGINT ignored) never gets.
        done = await until_stopped(
            show(url, root, args.once, args.timeout, sys.stdout), stop_on_signals()
        )
        return 0 if done is None else done

    try:
        return asyncio.run(main())
    except KeyboardInterrupt:
        return 0  # a Ctrl-C before the handlers are in place
