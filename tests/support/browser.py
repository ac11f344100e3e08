"""Pytest fixtures and helpers for driving the dashboard in real Chromium (a pytest plugin).

Load it with `pytest_plugins = ["support.browser"]` (tests/conftest.py does). Fixtures:
`chromium` (one headless browser per session) and `open_dashboard` (serve the app on a free port
and open it in a fresh page, connected to a broker).
"""

from __future__ import annotations

import contextlib
import re
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import expect

from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.server import DashboardServer
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.grid import GridMap
from gridfleet.system.broker_thread import BrokerThread

from support.paths import REPO
from support.wait import wait_for

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
ARTIFACTS = REPO / "test-artifacts"  # the repository's, as before
VIEWPORT = {"width": 1440, "height": 900}
# Every wait on the page is bounded, generously: a page on a machine shared with other test
# workers may take seconds to show what a quiet one shows at once (Playwright's `expect` would
# give up after 5 s).
WAIT_MS = 20_000
expect.set_options(timeout=WAIT_MS)


def as_typed(where: tuple[int, int] | str) -> str:
    """A pickup or dropoff as an operator types it into the job form: "X,Y", or a place's name."""
    return where if isinstance(where, str) else f"{where[0]},{where[1]}"


@dataclass
class OpenDashboard:
    """A dashboard served for one test and the Playwright page showing it."""

    page: Any  # playwright.sync_api.Page
    server: DashboardServer
    client_id: str
    errors: list[str]  # uncaught exceptions in the page

    def click_square(self, x: int, y: int) -> None:
        """Click the centre of square (x, y) on the map canvas."""
        canvas = self.page.locator("#map")
        # Once the map is drawn (at most a tenth of a second after it arrives) it has a layout.
        wait_in_page(self.page, "document.querySelector('#map').dataset.cell !== undefined")
        cell, ox, oy = (
            float(canvas.get_attribute(f"data-{k}") or "nan") for k in ("cell", "ox", "oy")
        )
        canvas.click(position={"x": ox + (x + 0.5) * cell, "y": oy + (y + 0.5) * cell})

    def drawn_units(self) -> dict[str, tuple[int, int]]:
        """Where the map canvas last drew each unit."""
        text = self.page.locator("#map").get_attribute("data-units") or ""
        found: dict[str, tuple[int, int]] = {}
        for item in text.split():
            unit, _, square = item.partition("@")
            x, y = square.split(",")
            found[unit] = (int(x), int(y))
        return found

    def wait_for_map(self) -> None:
        """Wait until the page shows the coordinator's map (its forms refuse every square before)."""
        # A form sent sooner is answered "no map yet" (CI failed on that once, under load).
        expect(self.page.locator("#map-name")).not_to_have_text("no map yet")

    def submit_job(
        self,
        pickup: tuple[int, int] | str,
        dropoff: tuple[int, int] | str,
        mass_kg: float,
        priority: int = 0,
        job_id: str | None = None,
    ) -> None:
        """Fill the job form and press "queue job" (as an operator would, once the map shows).

        `pickup` and `dropoff`: a square (typed as "X,Y") or a place's name.
        """
        self.wait_for_map()
        form = self.page.locator("#job-form")
        values = {
            "pickup": as_typed(pickup),
            "dropoff": as_typed(dropoff),
            "mass": mass_kg,
            "priority": priority,
            "job_id": job_id or "",
        }
        for name, value in values.items():
            form.locator(f"input[name={name}]").fill(str(value))
        form.locator("button[type=submit]").click()

    def set_goal(self, unit: str, target: tuple[int, int]) -> None:
        """Choose `unit` and send it to `target` with the goal form, once the map shows."""
        self.wait_for_map()
        form = self.page.locator("#goal-form")
        form.locator("select[name=unit]").select_option(unit)
        form.locator("input[name=x]").fill(str(target[0]))
        form.locator("input[name=y]").fill(str(target[1]))
        form.locator("button[type=submit]").click()

    def cancel_job(self, job_id: str) -> None:
        """Press the job's "delete" button in the queue."""
        self.page.locator(f"#jobs button[data-cancel='{job_id}']").click()

    def press_stop(self) -> None:
        """One click on STOP."""
        self.page.locator("#stop").click()

    def hold_release(self) -> None:
        """Press and hold "hold to release" until the page has released the stop."""
        self.page.locator("#release").hover()
        self.page.mouse.down()
        try:
            self.page.wait_for_selector("#release", state="hidden", timeout=10000)
        finally:
            self.page.mouse.up()

    def screenshot(self, name: str) -> Path:
        """Save a full-page screenshot under test-artifacts/ and return its path."""
        ARTIFACTS.mkdir(exist_ok=True)
        path = ARTIFACTS / f"{re.sub(r'[^A-Za-z0-9_.-]', '_', name)}.png"
        self.page.screenshot(path=str(path))
        return path

    def wait_connected(self, timeout_ms: float = 15000) -> None:
        """Wait until the page says it is connected to the broker (and subscribed)."""
        self.page.wait_for_selector("#conn[data-state=connected]", timeout=timeout_ms)


# Module scope, not session: Playwright's sync API keeps an event loop running on this thread
# while it is open, which would break every async test collected after it.
@pytest.fixture(scope="module")
def chromium() -> Iterator[Any]:
    """One headless Debian Chromium per test module (skips when it is not installed)."""
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is not installed (apt-get install chromium; .ci/run does)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS
        )
        yield browser
        browser.close()


@pytest.fixture
def open_dashboard(
    chromium: Any, broker: BrokerThread, root: str
) -> Iterator[Callable[..., OpenDashboard]]:
    """Factory: serve the dashboard for the test's topic root, open it connected to a broker
    (the suite's, or `via`), which is told the page's origin."""
    opened: list[tuple[Any, DashboardServer]] = []
    test_root = root

    def open_(
        root: str = test_root,
        *,
        via: BrokerThread | None = None,
        broker_ws: str | None = None,
        grid: GridMap | None = None,
        colors: dict[str, str] | None = None,
        client_id: str = "dash-test",
        wait_connected: bool = True,
        viewport: dict[str, int] | None = None,
        **settings_kw: Any,
    ) -> OpenDashboard:
        used = via or broker
        settings = DashboardSettings(
            broker_ws=broker_ws or used.ws_url,
            root=root,
            map=grid,
            colors=colors or {},
            **settings_kw,
        )
        server = DashboardServer(create_app(settings)).start()
        # The broker lets in no page but the dashboard's, whose port is known only now.
        used.allow_origins(server.url)
        context = chromium.new_context(viewport=viewport or VIEWPORT)
        opened.append((context, server))
        page = context.new_page()
        page.set_default_timeout(WAIT_MS)
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        # Whatever the page's Content Security Policy blocks counts as an error of the page.
        page.on("console", lambda m: "Content Security Policy" in m.text and errors.append(m.text))
        page.goto(f"{server.url}/?client={client_id}")
        handle = OpenDashboard(page, server, client_id, errors)
        if wait_connected:
            handle.wait_connected()
        return handle

    yield open_
    for context, server in opened:
        context.close()
        server.stop()


# Subscribe, publish, and resolve with what came back (or with how the connection ended).
EXCHANGE = """url => new Promise(done => {
    const client = mqtt.connect(url, {clientId: 'exchange-page', reconnectPeriod: 0});
    client.on('connect', () => client.subscribe('exchange/page', () => client.publish('exchange/page', 'hi')));
    client.on('message', (topic, payload) => { done('got ' + payload); client.end(); });
    client.on('error', error => done('error ' + error.message));
    client.on('close', () => done('closed'));
})"""


class _BlankPage(BaseHTTPRequestHandler):
    def do_GET(self) -> None:
        body = b"<html><body></body></html>"
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, format: str, *args: Any) -> None:
        pass


@contextlib.contextmanager
def blank_page_server() -> Iterator[int]:
    """An empty HTML page served on 127.0.0.1 at a free port (yields the port).

    A page needs a real local origin: Chromium's Local Network Access checks block a page it
    cannot place (about:blank, a routed one) from opening a websocket to loopback.
    """
    server = ThreadingHTTPServer(("127.0.0.1", 0), _BlankPage)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield int(server.server_address[1])
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


def wait_in_page(page: Any, expression: str, timeout: float = 10.0) -> None:
    """Wait until `expression` (or `() => …`) is truthy in `page`.

    Not Playwright's wait_for_function: that evaluates its predicate with eval() inside the page,
    which the dashboard's Content Security Policy forbids (as it should); evaluate() does not.
    """
    wait_for(lambda: page.evaluate(expression), timeout, interval=0.05, what=expression[:80])
