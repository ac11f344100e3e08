"""The dashboard at fleet scale: the page's frame budget in headless Chromium, and its cost to the fleet.

`gridfleet bench page` starts `gridfleet up --demo` on the system bench's generated map, then
alternates phases with the page closed and open. While open it counts animation frames and long
tasks inside the page, times a trivial evaluate (the delay any input would see) and reads the
renderer's CPU time; in every phase it counts the coordinator's steps (from `fleet/routes`).
"""

from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import psutil
from paho.mqtt.enums import CallbackAPIVersion

from gridfleet.bench.busy_scenario import make_busy
from gridfleet.errors import ConfigError
from gridfleet.lifeline import PARENT_ENV
from gridfleet.ports import free_port
from gridfleet.protocol import SUBSCRIBE_QOS, TOPICS, JobsView, Routes, Topics, decode

CHROMIUM = Path("/usr/bin/chromium")
ROUTES_WAIT_S = 60.0  # how long the bench waits for a started fleet's first routes
# Counted inside the page from its first script on: frames drawn, and tasks over 50 ms.
PROBE = """
window.__bench = {frames: 0, long: [], since: performance.now()};
(function count() { window.__bench.frames += 1; requestAnimationFrame(count); })();
new PerformanceObserver((list) => {
  for (const e of list.getEntries()) window.__bench.long.push(e.duration);
}).observe({type: "longtask", buffered: true});
"""
READ_PROBE = """() => {
  const b = window.__bench, now = performance.now();
  const out = {frames: b.frames, long: b.long.slice(), ms: now - b.since};
  b.frames = 0; b.long = []; b.since = now;
  return out;
}"""


@dataclass
class OpenPhase:
    """What one phase with the page open measured."""

    fps: float
    long_tasks: int
    long_task_ms_max: float
    busy_share: float  # of the phase, the time in long tasks
    input_delay_ms_mean: float
    input_delay_ms_p95: float
    renderer_cpu_pct: float
    renderer_rss_mb: float
    steps_per_s: float


@dataclass
class PageResult:
    """Every phase, and the medians the targets are read against."""

    units: int
    step_s: float
    viewport: str
    phase_s: float
    closed_steps_per_s: list[float] = field(default_factory=list)
    open: list[OpenPhase] = field(default_factory=list)
    jobs_view_bytes: list[int] = field(default_factory=list)
    jobs_view_listed: list[int] = field(default_factory=list)
    routes_bytes: int = 0

    def summary(self) -> dict[str, Any]:
        """Medians over the open phases, and the step rate open against closed."""

        def med(name: str) -> float:
            return round(float(statistics.median(getattr(p, name) for p in self.open)), 2)

        closed = statistics.median(self.closed_steps_per_s)
        opened = med("steps_per_s")
        return {
            "fps": med("fps"),
            "long_tasks_per_30s": round(
                statistics.median(p.long_tasks for p in self.open) * 30 / self.phase_s, 1
            ),
            "long_task_ms_max": max(p.long_task_ms_max for p in self.open),
            "input_delay_ms_p95": med("input_delay_ms_p95"),
            "renderer_cpu_pct": med("renderer_cpu_pct"),
            "renderer_rss_mb": med("renderer_rss_mb"),
            "steps_per_s_closed": round(closed, 2),
            "steps_per_s_open": opened,
            "open_over_closed": round(opened / closed, 3) if closed else None,
            "jobs_view_bytes_max": max(self.jobs_view_bytes, default=0),
            "jobs_view_bytes_per_job_max": max(
                (
                    round(b / n)
                    for b, n in zip(self.jobs_view_bytes, self.jobs_view_listed, strict=True)
                    if n
                ),
                default=0,
            ),
            "routes_bytes_max": self.routes_bytes,
        }


class StepCounter:
    """Counts the coordinator's steps from its routes, and keeps the largest jobs view seen."""

    def __init__(self, port: int, topics: Topics) -> None:
        self.step: int | None = None
        self.jobs_bytes: list[int] = []
        self.jobs_listed: list[int] = []  # jobs each view listed (under way and finished)
        self.routes_bytes = 0
        self._topics = topics
        self._client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="bench-page-steps")
        self._client.on_message = self._on_message
        self._client.connect("127.0.0.1", port)
        self._client.subscribe(
            [(topics.fleet("routes"), SUBSCRIBE_QOS), (topics.fleet("jobs"), SUBSCRIBE_QOS)]
        )
        self._client.loop_start()

    def _on_message(self, _c: object, _u: object, msg: mqtt.MQTTMessage) -> None:
        if msg.topic == self._topics.fleet("jobs"):
            view = decode(JobsView, msg.payload, TOPICS["jobs"].max_bytes)
            self.jobs_bytes.append(len(msg.payload))
            self.jobs_listed.append(len(view.jobs) + len(view.finished))
            return
        self.routes_bytes = max(self.routes_bytes, len(msg.payload))
        self.step = decode(Routes, msg.payload, TOPICS["routes"].max_bytes).step

    def wait_for_routes(self, timeout: float = ROUTES_WAIT_S) -> None:
        """Until the coordinator's first routes have come (a starved start takes seconds)."""
        deadline = time.monotonic() + timeout
        while self.step is None:
            if time.monotonic() > deadline:
                raise ConfigError("no routes from the coordinator: is the fleet running?")
            time.sleep(0.05)  # polling a value the MQTT thread sets, with a deadline

    def rate_over(self, seconds: float) -> float:
        """Steps a second over the next `seconds`."""
        first, t0 = self.step, time.monotonic()
        time.sleep(seconds)
        last, t1 = self.step, time.monotonic()
        if first is None or last is None:
            raise ConfigError("no routes from the coordinator: is the fleet running?")
        return (last - first) / (t1 - t0)

    def close(self) -> None:
        """Disconnect."""
        self._client.loop_stop()
        self._client.disconnect()


@contextmanager
def running_fleet(units: int, jobs: int, step: float, seed: int) -> Iterator[tuple[int, int]]:
    """`gridfleet up --demo` on the generated map with `jobs` queued; yields (mqtt, web) ports."""
    with tempfile.TemporaryDirectory(prefix="gridfleet-bench-page-") as tmp:
        scenario = make_busy(units, jobs, seed, Path(tmp))
        mqtt_port, ws_port, web_port = free_port(), free_port(), free_port()
        cmd = [sys.executable, "-m", "gridfleet", "up", "--demo", "--scenario"]
        cmd += [str(scenario.path), "--step", str(step), "--mqtt-port", str(mqtt_port)]
        cmd += ["--ws-port", str(ws_port), "--port", str(web_port), "--db", f"{tmp}/jobs.db"]
        log = open(f"{tmp}/up.log", "wb")  # noqa: SIM115 - closed below, after the process
        # The fleet ends with this process however it ends (a bench killed left one running).
        env = {**os.environ, PARENT_ENV: str(os.getpid())}
        proc = subprocess.Popen(
            cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, env=env
        )
        try:
            _await_page(web_port, proc, Path(f"{tmp}/up.log"))
            yield mqtt_port, web_port
        finally:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            log.close()


def _await_page(port: int, proc: subprocess.Popen[bytes], log: Path) -> None:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ConfigError(f"gridfleet up exited: {log.read_text()[-2000:]}")
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2):
                return
        except OSError:
            time.sleep(0.2)
    raise ConfigError("the dashboard did not answer within 60 s")


def _renderers() -> list[psutil.Process]:
    """This process's Chromium renderers (under Playwright's driver and the browser)."""
    kids = psutil.Process().children(recursive=True)
    return [p for p in kids if "--type=renderer" in " ".join(p.cmdline())]


MIN_INPUTS = 6  # inputs an open phase gives the page, however long they take


def _p95(samples: list[float]) -> float:
    """The 95th percentile; with one sample (an input that took the whole phase), that one."""
    return statistics.quantiles(samples, n=20)[-1] if len(samples) > 1 else max(samples)


def measure_open(
    page: Any, steps: StepCounter, seconds: float, until_a_step_s: float = 0.0
) -> OpenPhase:
    """One open phase: the page's frames, long tasks, input delay and CPU, and the step rate.

    `until_a_step_s`: the phase goes on, up to that long, until the fleet has made a step.
    """
    renderers = _renderers()
    cpu0 = sum(sum(p.cpu_times()[:2]) for p in renderers)
    page.evaluate(READ_PROBE)  # start counting now
    first, t0 = steps.step, time.monotonic()
    delays: list[float] = []
    # A phase is its span and at least a few inputs: on a starved machine one input can take the
    # whole span (CI: 5.7 s, in which the step counter saw no step), which measures the stall only.
    while (
        time.monotonic() - t0 < seconds
        or len(delays) < MIN_INPUTS
        or (steps.step == first and time.monotonic() - t0 < until_a_step_s)
    ):
        a = time.perf_counter()
        page.evaluate("1")
        delays.append((time.perf_counter() - a) * 1000)
        time.sleep(0.25)
    probe = page.evaluate(READ_PROBE)
    elapsed = time.monotonic() - t0
    cpu1 = sum(sum(p.cpu_times()[:2]) for p in renderers)
    rss = sum(p.memory_info().rss for p in renderers) / 2**20
    long = probe["long"]
    last = steps.step
    return OpenPhase(
        fps=round(probe["frames"] / (probe["ms"] / 1000), 1),
        long_tasks=len(long),
        long_task_ms_max=round(max(long, default=0.0), 1),
        busy_share=round(sum(long) / probe["ms"], 3),
        input_delay_ms_mean=round(statistics.fmean(delays), 1),
        input_delay_ms_p95=round(_p95(delays), 1),
        renderer_cpu_pct=round(100 * (cpu1 - cpu0) / elapsed, 1),
        renderer_rss_mb=round(rss, 1),
        steps_per_s=round(((last or 0) - (first or 0)) / elapsed, 2),
    )


def run_page_bench(
    units: int,
    jobs: int,
    step: float,
    phase_s: float,
    phases: int,
    viewport: tuple[int, int],
    screenshot: Path | None = None,
    seed: int = 1,
    warmup_s: float = 20.0,
    until_a_step_s: float = 0.0,
) -> PageResult:
    """Alternate closed and open phases on one running fleet; every figure of every phase.

    `until_a_step_s`: each open phase goes on, up to that long, until the fleet has made a step.
    """
    try:
        from playwright.sync_api import sync_playwright
    except ImportError as exc:  # a test extra: say how to get it
        raise ConfigError("bench page needs Playwright: pip install -e '.[bench]'") from exc
    if not CHROMIUM.exists():
        raise ConfigError(f"bench page needs Chromium at {CHROMIUM} (apt-get install chromium)")
    result = PageResult(units, step, f"{viewport[0]}x{viewport[1]}", phase_s)
    with running_fleet(units, jobs, step, seed) as (mqtt_port, web_port), sync_playwright() as pw:
        steps = StepCounter(mqtt_port, Topics("gridfleet"))
        browser = pw.chromium.launch(
            executable_path=str(CHROMIUM), args=["--no-sandbox", "--disable-gpu"]
        )
        try:
            # Past the first allocation of every queued job: the figures are the steady fleet's.
            steps.wait_for_routes()  # CI: none yet 2 s in, on a starved machine
            steps.rate_over(warmup_s)
            for _ in range(phases):
                result.closed_steps_per_s.append(round(steps.rate_over(phase_s), 2))
                page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
                page.add_init_script(PROBE)
                page.goto(f"http://127.0.0.1:{web_port}/")
                # Polled with evaluate(): wait_for_function() evals in the page, which the
                # dashboard's Content Security Policy forbids.
                shown = "document.querySelectorAll('#units tbody tr').length > 0"
                deadline = time.monotonic() + 30
                while not page.evaluate(shown):
                    if time.monotonic() > deadline:
                        raise TimeoutError("the page showed no unit within 30 s")
                    time.sleep(0.05)
                time.sleep(2)  # the retained views arrived; measure the steady page
                result.open.append(measure_open(page, steps, phase_s, until_a_step_s))
                if screenshot is not None:
                    page.screenshot(path=str(screenshot))
                page.close()
            result.jobs_view_bytes = steps.jobs_bytes
            result.jobs_view_listed = steps.jobs_listed
            result.routes_bytes = steps.routes_bytes
        finally:
            browser.close()
            steps.close()
    return result


def report(result: PageResult, as_json: bool) -> str:
    """The result as JSON, or a table of the phases and the summary."""
    if as_json:
        return json.dumps(
            {
                "phases": [asdict(p) for p in result.open],
                **asdict(result),
                "summary": result.summary(),
            },
            indent=1,
        )
    lines = [
        f"{result.units} units, step {result.step_s} s, {result.viewport}, "
        f"{len(result.open)} x {result.phase_s:g} s closed/open"
    ]
    lines += [f"  open phase: {json.dumps(asdict(p))}" for p in result.open]
    lines += [f"  closed steps/s: {result.closed_steps_per_s}"]
    lines += [f"  {k}: {v}" for k, v in result.summary().items()]
    return "\n".join(lines)
