"""`gridfleet bench flood`: what one operator account's flood of valid requests does to the fleet.

Its own embedded broker with accounts, a coordinator (`--vouched-senders`, `--metrics`) and the
units of a generated scenario, each a process of its own, run from this checkout or from a wheel
of another (`--tree DIR`, repeatable: the trees alternate, `--repeat` runs each). A feeder keeps
as many jobs active as there are units. Phases: quiet, then a flood in which account `operator`
sends `--flood` valid submit_job requests as fast as one paho client can (QoS 1, reply_to set,
each its own id, feasible squares), measured until `--settle` s after every one is answered, or
`--deadline`.
Meanwhile a second operator (`operator2`) submits and cancels a job every `--probe-every`
seconds, re-sending them as the operator's clients do, and engages the stop `--stops` times a
phase. Per phase: the fleet's moves a second (the world's ground truth, the stops left out), the
coordinator's step period (its metrics), the answers to the flood and to the second operator,
the stop's latency to every unit's state, the jobs views one subscriber received; per run: the
broker's "dropping" lines.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import random
import re
import statistics
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gridfleet.accounts import Account, Accounts, default_accounts, new_password, write_accounts
from gridfleet.bench.figures import percentile
from gridfleet.bench.flood_clients import Asked, FleetWatch, MetricsSampler, Requester, ViewCount
from gridfleet.bench.flood_tree import (
    Components,
    Layout,
    Tree,
    this_checkout,
    wait_until,
    wheel_tree,
)
from gridfleet.bench.system.scenario import make_scenario
from gridfleet.config import check_step
from gridfleet.console.feed import random_job
from gridfleet.errors import ConfigError
from gridfleet.paths import DistanceFieldCache
from gridfleet.ports import free_port
from gridfleet.protocol import Topics
from gridfleet.scenario import Scenario
from gridfleet.squares import Cell

ROOT = "bench-flood"
STOP_WAIT_S = 20.0  # a stop not shown by every unit within this counts as never (None)
FIRST_STOP_S = 3.0  # into a phase, the first stop; then one every STOP_GAP_S
STOP_GAP_S = 5.0
FEEDER_INFLIGHT = 8  # the feeder's requests unanswered at most (as bench system's)
PROBE_ANSWER_S = 15.0  # how long past its phase an answer to operator2's last probe may come
WINDOW_S = 10.0  # the worst window of the fleet's moves


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The benchmark's options."""
    parser.add_argument("--flood", type=int, default=5000, help="requests flooded (default 5000)")
    parser.add_argument("--units", type=int, default=20, help="simulated units (default 20)")
    parser.add_argument("--step", type=float, default=0.2, help="step period, s (default 0.2)")
    parser.add_argument("--warmup", type=float, default=5.0, help="s before the quiet phase (5)")
    parser.add_argument("--quiet", type=float, default=15.0, help="the quiet phase, s (15)")
    parser.add_argument(
        "--deadline", type=float, default=120.0, help="the flood phase's end at most, s (120)"
    )
    parser.add_argument(
        "--settle",
        type=float,
        default=20.0,
        help="the flood phase goes on this long after its last answer, s (20; within --deadline)",
    )
    parser.add_argument("--stops", type=int, default=2, help="stops engaged a phase (default 2)")
    parser.add_argument(
        "--probe-every", type=float, default=2.0, help="operator2's submit+cancel every S s (2)"
    )
    parser.add_argument(
        "--tree",
        action="append",
        metavar="DIR",
        help="run broker, coordinator and units from a wheel of this checkout (repeatable: the "
        "trees alternate; default: this checkout as installed)",
    )
    parser.add_argument("--repeat", type=int, default=1, help="runs of each tree (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="map, starts and jobs (run k: +k)")
    parser.add_argument("--json", action="store_true", help="print JSON")


def run(args: argparse.Namespace) -> int:
    """Run every tree `--repeat` times, alternating; print a table or JSON."""
    if min(args.flood, args.units, args.repeat) < 1 or args.stops < 0:
        print(
            "--flood, --units and --repeat must be positive, --stops not negative", file=sys.stderr
        )
        return 2
    if min(args.warmup, args.quiet, args.deadline, args.probe_every) <= 0 or args.settle < 0:
        print(
            "--warmup, --quiet, --deadline and --probe-every must be positive, --settle not "
            "negative",
            file=sys.stderr,
        )
        return 2
    runs: list[dict[str, Any]] = []
    try:
        check_step(args.step)
        with tempfile.TemporaryDirectory(prefix="gridfleet-bench-flood-") as tmp:
            work = Path(tmp)
            trees = [wheel_tree(d, work) for d in args.tree] if args.tree else [this_checkout(work)]
            for tree in trees:
                print(f"bench flood: {tree.label} imports {tree.imports}", file=sys.stderr)
            for k in range(args.repeat):
                for tree in trees:
                    runs.append(one_run(tree, args, args.seed + k, work))
                    print(f"bench flood: run {len(runs)} done ({tree.label})", file=sys.stderr)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    summary = summarise(runs)
    if args.json:
        print(json.dumps({"runs": runs, "summary": summary}))
    else:
        print_table(summary)
    return 0


# ---- one run ------------------------------------------------------------------------------


def _accounts(scenario: Scenario) -> Accounts:
    """The fleet's accounts, a second operator, the feeder's and the instruments' (a viewer)."""
    accounts = default_accounts([u.id for u in scenario.units])
    for name, role in (("operator2", "operator"), ("feeder", "operator"), ("watch", "viewer")):
        accounts = accounts.with_account(Account(name, new_password(), role))  # type: ignore[arg-type]
    return accounts


@dataclass
class _Clients:
    """The bench's MQTT clients: the flood's, the second operator's, the feeder's, the watch."""

    flood: Requester
    probe: Requester
    feeder: Requester
    watch: FleetWatch
    views: ViewCount

    def all(self) -> list[Any]:
        """Every client."""
        return [self.flood, self.probe, self.feeder, self.watch, self.views]


@contextlib.contextmanager
def _clients(url: str, accounts: Accounts, topics: Topics, units: set[str]) -> Iterator[_Clients]:
    made: list[Any] = []
    try:
        made.append(Requester(url, accounts.get("operator"), "operator-flood", topics, inflight=0))
        made.append(Requester(url, accounts.get("operator2"), "operator2-probe", topics))
        made.append(Requester(url, accounts.get("feeder"), "feeder-jobs", topics))
        made.append(FleetWatch(url, accounts.get("watch"), "watch-fleet", topics, units))
        made.append(ViewCount(url, accounts.get("watch"), "watch-views", topics))
        for client in made:
            client.wait_ready()
        yield _Clients(*made)
    finally:
        for client in made:
            client.close()


def one_run(tree: Tree, args: argparse.Namespace, seed: int, work: Path) -> dict[str, Any]:
    """Start the components from `tree`, run the phases, stop them; the run's figures."""
    with tempfile.TemporaryDirectory(prefix="run-", dir=work) as tmp:
        here = Path(tmp)
        scenario = make_scenario(args.units, seed, here)
        accounts = _accounts(scenario)
        write_accounts(accounts, here / "accounts.toml")
        layout = Layout(
            accounts=here / "accounts.toml",
            scenario=scenario.path,
            map=scenario.map_path,
            db=here / "jobs.db",
            truth=here / "truth.jsonl",
            root=ROOT,
            step_s=args.step,
            metrics_port=free_port(),
        )
        components = Components(tree, layout, here)
        try:
            url = components.start()
            phases = _phases(url, accounts, scenario, components, layout, args, seed)
        finally:
            components.stop()
        truth = _read_truth(layout.truth)
        for figures, window in phases.values():
            figures.update(_moves(truth, window))
        return {
            "tree": tree.label,
            "imports": tree.imports,
            "seed": seed,
            "units": args.units,
            "step_s": args.step,
            "flood": args.flood,
            "phases": {name: figures for name, (figures, _) in phases.items()},
            "broker_dropping": components.dropping(),
        }


@dataclass
class _Window:
    """A phase's wall-clock span and the stops within it (their moves are left out)."""

    start: float
    end: float = 0.0
    stopped: list[tuple[float, float]] = field(default_factory=list)


class _Loop:
    """What goes on beside a phase: the feeder, operator2's probes and their re-sends."""

    def __init__(
        self,
        clients: _Clients,
        scenario: Scenario,
        rng: random.Random,
        sampler: MetricsSampler,
        every_s: float,
    ) -> None:
        self.c = clients
        self.scenario = scenario
        self.rng = rng
        self.fields = DistanceFieldCache(scenario.grid)
        self.sampler = sampler
        self.every_s = every_s
        self.next_feed = 0.0
        self.next_probe = math.inf
        self.probes: list[Asked] = []
        self.probe_jobs = 0

    def job(self) -> tuple[Cell, Cell, float]:
        """A random feasible job."""
        pickup, dropoff, mass = random_job(self.scenario, self.rng, self.fields)
        return pickup, dropoff, mass

    def probing(self, on: bool) -> None:
        """Start (now) or stop operator2's probes."""
        self.next_probe = time.monotonic() if on else math.inf

    def tick(self) -> None:
        """Do what is due."""
        now = time.monotonic()
        if now >= self.next_feed:
            self.next_feed = now + 1.0
            latest = self.sampler.latest()
            if latest is not None:
                pending = self.c.feeder.pending(now, 30.0)
                deficit = len(self.scenario.units) - int(latest.active_jobs) - pending
                for _ in range(max(0, min(deficit, FEEDER_INFLIGHT - pending))):
                    self.c.feeder.submit(*self.job())
        if now >= self.next_probe:
            self.next_probe = now + self.every_s
            self.probe_jobs += 1
            job_id = f"probe-{self.probe_jobs}"
            self.probes.append(self.c.probe.submit(*self.job(), job_id=job_id, retry=True))
            if self.probe_jobs > 1:
                previous = f"probe-{self.probe_jobs - 1}"
                self.probes.append(self.c.probe.cancel(previous, retry=True))
        self.c.probe.resend_due(now)

    def run_until(self, until: float, done: Any = None) -> None:
        """Tick until `until` (monotonic) or until `done()`."""
        while time.monotonic() < until and not (done is not None and done()):
            self.tick()
            time.sleep(0.02)  # pacing the ticks


def _phases(
    url: str,
    accounts: Accounts,
    scenario: Scenario,
    components: Components,
    layout: Layout,
    args: argparse.Namespace,
    seed: int,
) -> dict[str, tuple[dict[str, Any], _Window]]:
    topics = Topics(layout.root)
    units = {u.id for u in scenario.units}
    with _clients(url, accounts, topics, units) as clients:
        watch = clients.watch
        wait_until(
            lambda: watch.coordinator_online and units <= watch.planned,
            60,
            "the coordinator did not plan for every unit",
            components.check,
        )
        sampler = MetricsSampler(layout.metrics_port)
        sampler.start()
        try:
            wait_until(lambda: sampler.latest() is not None, 30, "no metrics", components.check)
            loop = _Loop(clients, scenario, random.Random(seed), sampler, args.probe_every)
            loop.run_until(time.monotonic() + args.warmup)  # the warm-up: pacing
            quiet = _phase(loop, clients, sampler, topics, args, flood=0)
            components.check()
            flood = _phase(loop, clients, sampler, topics, args, flood=args.flood)
            components.check()
        finally:
            sampler.stop()
    return {"quiet": quiet, "flood": flood}


def _phase(
    loop: _Loop,
    clients: _Clients,
    sampler: MetricsSampler,
    topics: Topics,
    args: argparse.Namespace,
    flood: int,
) -> tuple[dict[str, Any], _Window]:
    """One phase: the flood (if any) sent, the stops engaged, the rest measured meanwhile."""
    jobs = [loop.job() for _ in range(flood)]  # drawn before the phase: not in its time
    views0 = (clients.views.count, clients.views.bytes)
    clients.views.largest = 0
    probes0 = len(loop.probes)
    flooded: list[Asked] = []
    answered0 = clients.flood.answered  # replies to floods before this phase
    window = _Window(time.time())
    t0 = time.monotonic()
    loop.probing(True)
    for pickup, dropoff, mass in jobs:
        flooded.append(clients.flood.submit(pickup, dropoff, mass))
    sent_s = time.monotonic() - t0
    stops: list[float | None] = []

    def flood_answered() -> bool:
        return bool(clients.flood.answered - answered0 >= len(flooded))

    end = t0 + (args.deadline if flood else args.quiet)
    for k in range(args.stops):
        loop.run_until(t0 + FIRST_STOP_S + k * STOP_GAP_S)
        if time.monotonic() >= end:
            break
        stops.append(_stop(clients, topics, window))
    if flood:
        loop.run_until(end, flood_answered)
        answers = [a.answered for a in flooded if a.answered is not None]
        if answers and flood_answered():  # the fleet after the flood: within the deadline
            loop.run_until(min(end, max(answers) + args.settle))
    else:
        loop.run_until(end)
    t1 = time.monotonic()
    window.end = time.time()
    loop.probing(False)
    count, size = clients.views.count - views0[0], clients.views.bytes - views0[1]
    largest = clients.views.largest
    # A probe sent just before the end has its answer on the way: it counts (a while at most;
    # its time is its own, the phase's figures stop at t1).
    mine = loop.probes[probes0:]
    loop.run_until(t1 + PROBE_ANSWER_S, lambda: all(p.answered is not None for p in mine))
    figures: dict[str, Any] = {"duration_s": round(t1 - t0, 1)}
    figures |= _step_figures(sampler, t0, t1, clients.watch)
    if flood:
        figures["flood"] = _flood_figures(flooded, t0, sent_s, clients.flood)
    probes = loop.probes[probes0:]
    for kind in ("submit_job", "cancel_job"):
        figures[f"operator2_{kind}"] = _answers([p for p in probes if p.kind == kind])
    figures["stop_ms"] = stops
    figures["stop_ms_median"] = _median(stops)
    figures["jobs_views"] = count
    figures["jobs_views_mb"] = round(size / 1e6, 1)
    figures["jobs_view_largest_kb"] = round(largest / 1e3, 1)
    return figures, window


def _stop(clients: _Clients, topics: Topics, window: _Window) -> float | None:
    """Engage the latch as operator2; ms until every unit's state shows it stopped (None:
    not within STOP_WAIT_S); then release it and wait until every unit shows that."""
    latch = topics.fleet("estop")
    watch = clients.watch
    began_wall = time.time()
    shown = watch.expect(True)
    t0 = time.monotonic()
    clients.probe.engage(latch, True, "flood bench")
    ms = None
    if watch.all_shown.wait(STOP_WAIT_S):
        ms = round((max(shown.at.values()) - t0) * 1000, 1)
    watch.expect(False)
    clients.probe.engage(latch, False, "flood bench")
    watch.all_shown.wait(STOP_WAIT_S)
    window.stopped.append((began_wall, time.time()))
    return ms


# ---- figures ------------------------------------------------------------------------------


def _percentile(values: Sequence[float], q: float) -> float | None:
    """The measured value at or above quantile `q`, to 0.1; None when it is infinite (never)."""
    value = percentile(values, q)
    return None if value is None else round(value, 1)


def _median(values: Sequence[float | None]) -> float | None:
    """The median, None (never) counting as infinite; None when the median is."""
    if not values:
        return None
    median = statistics.median([math.inf if v is None else v for v in values])
    return None if math.isinf(median) else float(f"{median:.4g}")


def _reason_kind(reason: str | None) -> str:
    """A refusal's reason with its numbers and ids blurred, so that alike ones are counted as one."""
    text = re.sub(r"\d+(\.\d+)?", "N", reason or "(no reason)")
    return re.sub(r"'[^']*'", "'…'", text)[:120]


def _answers(asked: Sequence[Asked]) -> dict[str, Any]:
    """How a set of requests was answered: how many, how fast, refused why."""
    ms = [math.inf if a.answer_ms is None else a.answer_ms for a in asked]
    refused = Counter(_reason_kind(a.reason) for a in asked if a.accepted is False)
    return {
        "sent": len(asked),
        "answered": sum(1 for a in asked if a.answered is not None),
        "refused": sum(refused.values()),
        "refused_why": dict(refused.most_common(5)),
        "tries": sum(a.tries for a in asked),
        "p50_ms": _percentile(ms, 0.5),
        "p99_ms": _percentile(ms, 0.99),
        "max_ms": _percentile(ms, 1.0),
    }


def _flood_figures(
    flooded: list[Asked], t0: float, sent_s: float, flood: Requester
) -> dict[str, Any]:
    """The flood's answers, and how long it took to send it and to answer all of it."""
    figures = _answers(flooded)
    figures["accepted"] = sum(1 for a in flooded if a.accepted)
    figures["sent_s"] = round(sent_s, 2)
    figures["acked_s"] = round(flood.last_ack - t0, 2) if flood.acked >= len(flooded) else None
    last = [a.answered for a in flooded]
    figures["all_answered_s"] = (
        None if any(t is None for t in last) else round(max(t or 0.0 for t in last) - t0, 1)
    )
    return figures


def _step_figures(
    sampler: MetricsSampler, t0: float, t1: float, watch: FleetWatch
) -> dict[str, Any]:
    """The coordinator's step period over the phase (its metrics; else the routes' steps)."""
    inside = [s for s in sampler.samples if t0 <= s.at <= t1]
    figures: dict[str, Any] = {"metrics_scrapes": len(inside)}
    if len(inside) >= 2 and inside[-1].steps > inside[0].steps:
        first, last = inside[0], inside[-1]
        figures["step_s"] = round((last.at - first.at) / (last.steps - first.steps), 3)
        figures["jobs_done"] = int(last.done - first.done)
    else:
        routes = [(at, n) for at, n in watch.steps if t0 <= at <= t1]
        steps = routes[-1][1] - routes[0][1] if len(routes) >= 2 else 0
        figures["step_s"] = round((routes[-1][0] - routes[0][0]) / steps, 3) if steps > 0 else None
        figures["jobs_done"] = None
    achieved = [s.achieved_s for s in inside if s.achieved_s is not None]
    figures["step_achieved_max_s"] = round(max(achieved), 3) if achieved else None
    figures["metrics_scrape_max_s"] = round(max((s.took_s for s in inside), default=0.0), 2)
    return figures


def _read_truth(path: Path) -> list[tuple[float, int]]:
    """(wall time, moves so far) of every line of the units' truth file."""
    out = []
    if path.exists():
        for line in path.read_text(encoding="utf-8").splitlines():
            with contextlib.suppress(ValueError, KeyError):
                d = json.loads(line)
                out.append((float(d["t"]), int(d["moves"])))
    return out


def _moves_at(truth: list[tuple[float, int]], t: float) -> float:
    """The world's moves so far at wall time `t`, between the truth lines around it."""
    before = [p for p in truth if p[0] <= t]
    after = [p for p in truth if p[0] >= t]
    if not before:
        return float(truth[0][1])
    if not after:
        return float(truth[-1][1])
    (ta, ma), (tb, mb) = before[-1], after[0]
    return float(ma) if tb == ta else ma + (mb - ma) * (t - ta) / (tb - ta)


def _moves(truth: list[tuple[float, int]], window: _Window) -> dict[str, Any]:
    """The fleet's moves a second over the window, its stops left out; and its worst 10 s."""
    if not truth:
        return {"moves_per_s": None, "moves_per_s_worst_10s": None}
    total = _moves_at(truth, window.end) - _moves_at(truth, window.start)
    span = window.end - window.start
    for a, b in window.stopped:
        total -= _moves_at(truth, b) - _moves_at(truth, a)
        span -= b - a
    worst = None
    t = window.start
    while t + WINDOW_S <= window.end:
        if not any(a < t + WINDOW_S and b > t for a, b in window.stopped):
            rate = (_moves_at(truth, t + WINDOW_S) - _moves_at(truth, t)) / WINDOW_S
            worst = rate if worst is None else min(worst, rate)
        t += 1.0
    return {
        "moves_per_s": round(total / span, 2) if span > 0 else None,
        "moves_per_s_worst_10s": None if worst is None else round(worst, 2),
    }


# ---- summary ------------------------------------------------------------------------------

# (figure's path in a phase, column heading): the table's columns, medians over the runs.
COLUMNS = (
    (("moves_per_s",), "moves/s"),
    (("moves_per_s_worst_10s",), "worst 10 s"),
    (("step_s",), "step s"),
    (("step_achieved_max_s",), "achieved max s"),
    (("jobs_done",), "jobs done"),
    (("flood", "answered"), "flood answered"),
    (("flood", "refused"), "refused"),
    (("flood", "p50_ms"), "flood p50 ms"),
    (("flood", "p99_ms"), "p99 ms"),
    (("flood", "max_ms"), "max ms"),
    (("flood", "all_answered_s"), "all answered s"),
    (("operator2_submit_job", "sent"), "op2 submits"),
    (("operator2_submit_job", "answered"), "answered"),
    (("operator2_submit_job", "p50_ms"), "op2 submit p50 ms"),
    (("operator2_submit_job", "max_ms"), "max ms"),
    (("operator2_cancel_job", "p50_ms"), "op2 cancel p50 ms"),
    (("operator2_cancel_job", "max_ms"), "max ms"),
    (("stop_ms_median",), "stop ms"),
    (("jobs_views",), "jobs views"),
    (("jobs_views_mb",), "MB"),
)


NEVER = ("p50_ms", "p99_ms", "max_ms", "all_answered_s", "stop_ms_median")  # None: not in time


def _get(phase: dict[str, Any], path: tuple[str, ...]) -> Any:
    value: Any = phase
    for key in path:
        if not isinstance(value, dict) or key not in value:
            return "absent"
        value = value[key]
    return value


def summarise(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per tree and phase: the median of each column over the runs (None: never)."""
    out = []
    for tree in dict.fromkeys(r["tree"] for r in runs):
        mine = [r for r in runs if r["tree"] == tree]
        for phase in ("quiet", "flood"):
            row: dict[str, Any] = {"tree": tree, "phase": phase, "runs": len(mine)}
            for path, _ in COLUMNS:
                values = [_get(r["phases"][phase], path) for r in mine]
                if all(v == "absent" for v in values):
                    continue
                row[".".join(path)] = _median([v for v in values if v != "absent"])
            dropping = sorted({d for r in mine for d in r["broker_dropping"]})
            row["broker_dropping"] = dropping if phase == "flood" else []
            out.append(row)
    return out


def print_table(summary: list[dict[str, Any]]) -> None:
    """The summary as a Markdown table (medians; `never` for a figure never reached)."""
    heads = [h for _, h in COLUMNS]
    print("| tree | phase | runs | " + " | ".join(heads) + " | broker dropping |")
    print("|---" * (len(heads) + 4) + "|")
    for row in summary:
        cells = []
        for path, _ in COLUMNS:
            key = ".".join(path)
            value = row.get(key, "")
            if key not in row:
                cells.append("")
            elif value is None:  # a time never reached; for the others, not measured
                cells.append("never" if key.endswith(NEVER) else "-")
            else:
                cells.append(f"{value:g}")
        dropping = ", ".join(row["broker_dropping"]) or "-"
        print(
            f"| {row['tree']} | {row['phase']} | {row['runs']} | "
            + " | ".join(cells)
            + f" | {dropping} |"
        )
