"""The API's docs page in real Chromium: Swagger UI from the wheel's own files renders the served
document under the page's own CSP (its one inline script let in by its hash), nothing blocked."""

from __future__ import annotations

from typing import Any

import pytest
from playwright.sync_api import expect

from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.server import DashboardServer
from gridfleet.dashboard.settings import DashboardSettings

pytestmark = pytest.mark.browser


def test_the_docs_page_shows_every_operation_and_its_csp_blocks_nothing(chromium: Any) -> None:
    server = DashboardServer(create_app(DashboardSettings(broker_ws="ws://127.0.0.1:9"))).start()
    context = chromium.new_context()
    try:
        page = context.new_page()
        problems: list[str] = []
        page.on("pageerror", lambda exc: problems.append(str(exc)))
        page.on(
            "console",
            lambda m: (
                ("Content Security Policy" in m.text or m.type == "error")
                and problems.append(m.text)
            ),
        )
        outside: list[str] = []
        page.on(
            "request",
            lambda r: (
                not r.url.startswith(server.url)
                and not r.url.startswith("data:")
                and outside.append(r.url)
            ),
        )
        page.goto(f"{server.url}/api/v1/docs")
        expect(page.locator(".swagger-ui .info .title")).to_contain_text("gridfleet HTTP API")
        expect(
            page.locator(".opblock-summary-path[data-path='/api/v1/jobs/{job_id}']").first
        ).to_be_visible()
        expect(page.locator(".opblock")).to_have_count(19)  # every operation of the document
        page.locator(".btn.authorize").first.click()  # the bearer scheme is offered
        expect(page.locator(".auth-container")).to_contain_text("bearer")
        assert problems == [], problems
        assert outside == [], outside  # no CDN, no validator badge
    finally:
        context.close()
        server.stop()
