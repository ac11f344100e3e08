"""`gridfleet bench api`: the HTTP API's requests a second with a fleet moving, and their cost to it.

Starts `gridfleet up --demo` on the system bench's generated map (`--units` units, `--jobs` random
jobs queued at the start), waits `--warmup` seconds, then alternates phases without and with API
clients: `--clients` threads, each a keep-alive HTTP client (httpx) sending a site's mix of
requests as fast as they are answered, or at `--rate` requests a second in all: the jobs view, one
job, the units, one unit, the stop, the places, and one write in ten (a job submitted with an
`Idempotency-Key`, cancelled by the next write). In every phase it counts the coordinator's steps
(from `fleet/routes`) and the dashboard's CPU; in a loaded phase, the answers by status and the
latency of each kind of request. Figures are medians over the phases of each kind.
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import json
import logging
import random
import statistics
import tempfile
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import psutil

from gridfleet.bench.busy_scenario import make_busy
from gridfleet.bench.figures import percentile
from gridfleet.bench.page import StepCounter, running_fleet
from gridfleet.config import check_step
from gridfleet.errors import ConfigError
from gridfleet.protocol import Topics

WRITE_EVERY = 10  # one request in this many is a write: a submit, or the cancel of the last one
READS = ("jobs", "job", "units", "unit", "stop", "places")


@dataclass(frozen=True)
class FleetFacts:
    """What the clients pick from: the units' ids and the map's free squares."""

    units: list[str]
    squares: list[tuple[int, int]]


@dataclass
class Phase:
    """What one phase measured (an idle phase has no requests)."""

    loaded: bool
    seconds: float
    steps_per_s: float
    dashboard_cpu_pct: float
    requests: int = 0
    requests_per_s: float = 0.0
    statuses: dict[str, int] = field(default_factory=dict)
    latency_ms: dict[str, dict[str, float]] = field(default_factory=dict)  # kind -> p50, p99


@dataclass
class ApiResult:
    """Every phase, and the medians the figures are read from."""

    units: int
    step_s: float
    clients: int
    rate: float | None
    phases: list[Phase] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        """Medians of each kind of phase, and the step rate loaded against idle."""
        idle = [p for p in self.phases if not p.loaded]
        loaded = [p for p in self.phases if p.loaded]

        def med(phases: list[Phase], name: str) -> float:
            return round(float(statistics.median(getattr(p, name) for p in phases)), 2)

        idle_steps, loaded_steps = med(idle, "steps_per_s"), med(loaded, "steps_per_s")
        kinds = sorted({k for p in loaded for k in p.latency_ms})
        statuses: Counter[str] = Counter()
        for p in loaded:
            statuses.update(p.statuses)
        return {
            "requests_per_s": med(loaded, "requests_per_s"),
            "steps_per_s_idle": idle_steps,
            "steps_per_s_loaded": loaded_steps,
            "loaded_over_idle": round(loaded_steps / idle_steps, 3) if idle_steps else None,
            "dashboard_cpu_pct_idle": med(idle, "dashboard_cpu_pct"),
            "dashboard_cpu_pct_loaded": med(loaded, "dashboard_cpu_pct"),
            "statuses": dict(sorted(statuses.items())),
            "latency_ms_p50": {
                k: round(statistics.median(p.latency_ms[k]["p50"] for p in loaded), 1)
                for k in kinds
            },
            "latency_ms_p99": {
                k: round(statistics.median(p.latency_ms[k]["p99"] for p in loaded), 1)
                for k in kinds
            },
        }


class Client(threading.Thread):
    """One API client: a keep-alive connection sending the mix until told to stop."""

    def __init__(
        self, base: str, fleet: FleetFacts, stop: threading.Event, interval_s: float, seed: int
    ) -> None:
        super().__init__(daemon=True)
        import httpx  # of the bench extra: imported only when the bench runs

        self._http = httpx.Client(base_url=base, timeout=30.0)
        self._fleet = fleet
        self._halt = stop
        self._interval = interval_s
        self._rng = random.Random(seed)
        self._job: str | None = None  # the last job it submitted, cancelled by its next write
        self._jobs: list[str] = []  # job ids seen in the jobs view
        self.samples: list[tuple[str, int, float]] = []  # (kind, status, ms)

    def run(self) -> None:
        """Send requests until stopped; at a rate, each at its slot."""
        next_at = time.monotonic()
        for n in itertools.count():
            if self._halt.is_set():
                break
            if self._interval:
                delay = next_at - time.monotonic()
                if delay > 0 and self._halt.wait(delay):
                    break
                next_at += self._interval
            kind = "write" if n % WRITE_EVERY == WRITE_EVERY - 1 else self._rng.choice(READS)
            started = time.perf_counter()
            kind, status = self._send(kind)
            self.samples.append((kind, status, (time.perf_counter() - started) * 1000))
        self._http.close()

    def _send(self, kind: str) -> tuple[str, int]:
        if kind == "write":
            if self._job is not None:
                job, self._job = self._job, None
                return "cancel", self._http.delete(f"/jobs/{job}").status_code
            free = self._rng.sample(self._fleet.squares, 2)
            answer = self._http.post(
                "/jobs",
                json={"pickup": list(free[0]), "dropoff": list(free[1]), "mass_kg": 0.5},
                headers={"Idempotency-Key": str(uuid.uuid4())},
            )
            if answer.status_code == 201:
                self._job = answer.json()["id"]
            return "submit", answer.status_code
        if kind == "jobs":
            answer = self._http.get("/jobs", params={"limit": 100})
            if answer.status_code == 200:
                self._jobs = [j["id"] for j in answer.json()["jobs"]][:50]
            return kind, answer.status_code
        if kind == "job":
            job = self._rng.choice(self._jobs) if self._jobs else "none"
            return kind, self._http.get(f"/jobs/{job}").status_code
        if kind == "unit":
            return kind, self._http.get(f"/units/{self._rng.choice(self._fleet.units)}").status_code
        return kind, self._http.get(f"/{kind}").status_code


def _ms(samples: list[float], q: float) -> float:
    """The measured latency at or above quantile `q`, to 0.1 ms (kinds without samples are not
    reported)."""
    value = percentile(samples, q)
    assert value is not None, "a kind is reported only with samples"
    return round(value, 1)


def _await_units(base: str, units: int, timeout_s: float = 60.0) -> list[str]:
    """The units' ids, once the API lists all `units` of them."""
    import httpx

    deadline = time.monotonic() + timeout_s
    while True:
        answer = httpx.get(f"{base}/units", timeout=30)
        listed = [u["id"] for u in answer.json()["units"]] if answer.status_code == 200 else []
        if len(listed) >= units:
            return listed
        if time.monotonic() > deadline:
            raise ConfigError(f"the API listed {len(listed)} of {units} units after {timeout_s} s")
        time.sleep(0.2)  # polling the API with a deadline


def _dashboard() -> psutil.Process:
    """The dashboard's process among `gridfleet up`'s (this process's descendants)."""
    for proc in psutil.Process().children(recursive=True):
        if "dashboard" in proc.cmdline():
            return proc
    raise ConfigError("gridfleet up started no dashboard process")


def _cpu(proc: psutil.Process) -> float:
    times = proc.cpu_times()
    return float(times.user + times.system)


def measure(
    steps: StepCounter,
    dashboard: psutil.Process,
    seconds: float,
    load: Callable[[threading.Event], list[Client]] | None,
) -> Phase:
    """One phase, idle (`load` None) or with the clients `load` makes, each stopped at its end by
    the event it is given."""
    stop = threading.Event()
    clients = load(stop) if load is not None else []
    cpu0, first, t0 = _cpu(dashboard), steps.step, time.monotonic()
    for c in clients:
        c.start()
    time.sleep(seconds)  # the phase's span: the clients and the fleet run meanwhile
    last, elapsed, cpu1 = steps.step, time.monotonic() - t0, _cpu(dashboard)
    phase = Phase(
        loaded=load is not None,
        seconds=round(elapsed, 1),
        steps_per_s=round(((last or 0) - (first or 0)) / elapsed, 2),
        dashboard_cpu_pct=round(100 * (cpu1 - cpu0) / elapsed, 1),
    )
    if clients:
        stop.set()
        for c in clients:
            c.join(60)
        samples = [s for c in clients for s in c.samples]
        phase.requests = len(samples)
        phase.requests_per_s = round(len(samples) / elapsed, 1)
        phase.statuses = dict(Counter(str(status) for _, status, _ in samples))
        by_kind: dict[str, list[float]] = {}
        for kind, _, ms in samples:
            by_kind.setdefault(kind, []).append(ms)
        phase.latency_ms = {
            k: {q: _ms(v, at) for q, at in (("p50", 0.5), ("p99", 0.99))}
            for k, v in sorted(by_kind.items())
        }
    return phase


def run_api_bench(
    units: int,
    jobs: int,
    step: float,
    clients: int,
    rate: float | None,
    phase_s: float,
    phases: int,
    warmup_s: float,
    seed: int = 1,
) -> ApiResult:
    """Alternate idle and loaded phases on one running fleet; every figure of every phase."""
    if importlib.util.find_spec("httpx") is None:
        raise ConfigError("bench api needs httpx: pip install -e '.[bench]'")
    logging.getLogger("httpx").setLevel(logging.WARNING)  # a line a request otherwise
    result = ApiResult(units, step, clients, rate)
    with tempfile.TemporaryDirectory(prefix="gridfleet-bench-api-") as tmp:
        squares = [(c.x, c.y) for c in make_busy(units, 0, seed, Path(tmp)).grid.free_cells()]
    with running_fleet(units, jobs, step, seed) as (mqtt_port, web_port):
        steps = StepCounter(mqtt_port, Topics("gridfleet"))
        try:
            steps.wait_for_routes()
            base = f"http://127.0.0.1:{web_port}/api/v1"
            fleet = FleetFacts(units=_await_units(base, units), squares=squares)
            dashboard = _dashboard()
            steps.rate_over(warmup_s)
            interval = clients / rate if rate else 0.0
            for n in range(phases):
                result.phases.append(measure(steps, dashboard, phase_s, None))

                def load(stop: threading.Event, n: int = n) -> list[Client]:
                    return [
                        Client(base, fleet, stop, interval, seed * 1000 + n * 100 + i)
                        for i in range(clients)
                    ]

                result.phases.append(measure(steps, dashboard, phase_s, load))
        finally:
            steps.close()
    return result


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet bench api`."""
    parser.add_argument("--units", type=int, default=100, help="units (default 100)")
    parser.add_argument(
        "--jobs", type=int, default=300, help="jobs queued at the start (default 300)"
    )
    parser.add_argument("--step", type=float, default=0.1, help="step period, s (default 0.1)")
    parser.add_argument(
        "--clients", type=int, default=4, help="API clients at once, each one connection (4)"
    )
    parser.add_argument(
        "--rate",
        type=float,
        help="requests a second of all the clients together (default: as fast as answered)",
    )
    parser.add_argument(
        "--phase", type=float, default=20.0, help="seconds of each idle and loaded phase (20)"
    )
    parser.add_argument(
        "--warmup", type=float, default=20.0, help="seconds before the first phase (default 20)"
    )
    parser.add_argument("--phases", type=int, default=3, help="idle/loaded pairs (default 3)")
    parser.add_argument("--json", action="store_true", help="print JSON")


def report(result: ApiResult, as_json: bool) -> str:
    """The result as JSON, or a line per phase and the summary."""
    if as_json:
        return json.dumps({**asdict(result), "summary": result.summary()}, indent=1)
    rate = f"{result.rate:g} requests/s" if result.rate else "as fast as answered"
    lines = [
        f"{result.units} units, step {result.step_s} s, {result.clients} clients ({rate}), "
        f"{len(result.phases) // 2} x idle/loaded"
    ]
    lines += [f"  phase: {json.dumps(asdict(p))}" for p in result.phases]
    lines += [f"  {k}: {v}" for k, v in result.summary().items()]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the bench and print its figures."""
    check_step(args.step)
    if args.units < 1 or args.jobs < 0 or args.clients < 1 or args.phases < 1:
        raise ConfigError("--units ≥ 1, --jobs ≥ 0, --clients ≥ 1, --phases ≥ 1")
    if args.phase < 5 or args.warmup < 0 or (args.rate is not None and args.rate <= 0):
        raise ConfigError("--phase ≥ 5, --warmup ≥ 0, --rate > 0")
    result = run_api_bench(
        args.units,
        args.jobs,
        args.step,
        args.clients,
        args.rate,
        args.phase,
        args.phases,
        args.warmup,
    )
    print(report(result, args.json))
    return 0
