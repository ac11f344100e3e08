"""The page's side of closed zones without a browser: the settings say who may close and open
them, and the page's reading of `fleet/zones` (dashboard/static/js/zones.js, run by Node) refuses
exactly the views the zones view's JSON Schema refuses (protocol/schemas/ZonesView.json)."""

from __future__ import annotations

import json
import shutil
import subprocess

import pytest
from hypothesis import given

from gridfleet.accounts import Account, default_accounts, new_password
from gridfleet.dashboard.settings import DashboardSettings, settings_payload

from support.paths import REPO
from support.schema_inputs import NotJson, allowed, edge_settings, near_misses, parsed, payloads

DASHBOARD = REPO / "dashboard"
# The header is every view's, and the page reads no view's: each drawn view gets a good one.
HEADER = {"version": "1.6", "seq": 0, "timestamp": "2026-11-21T10:00:00Z", "sender": "coordinator"}
# Reads JSON texts (a list, on standard input) as the page's FleetView does, and says of each
# whether the page keeps it: true, or the words it logs.
JUDGE = """
import { readFileSync } from "node:fs";
import { readZones } from "./static/js/zones.js";
const texts = JSON.parse(readFileSync(0, "utf8"));
const verdicts = texts.map((text) => {
  let msg;
  try { msg = JSON.parse(text); } catch { return "not JSON"; }
  const read = readZones(msg);
  return read.error ?? true;
});
process.stdout.write(JSON.stringify(verdicts));
"""


def test_the_settings_offer_closing_and_opening_zones_to_people_not_viewers() -> None:
    # Without accounts anybody may, as the coordinator then allows.
    assert settings_payload(DashboardSettings(), True)["may_change"] is True
    accounts = default_accounts(["unit1"])
    settings = DashboardSettings(accounts=accounts)
    for name in ("operator", "dashboard"):
        assert settings_payload(settings, True, accounts.accounts[name])["may_change"] is True
    viewer = Account("vera", new_password(), "viewer")
    assert settings_payload(settings, True, viewer)["may_change"] is False


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
@pytest.mark.skipif(shutil.which("node") is None, reason="Node.js is not installed")
def test_the_page_keeps_exactly_the_zones_views_their_schema_allows() -> None:
    drawn: list[bytes] = []

    @edge_settings(200)
    @given(payload=payloads("zones") | near_misses("zones"))  # a near miss of its header is fine
    def draw(payload: bytes) -> None:
        drawn.append(payload)

    draw()
    texts: list[str] = []
    expected: list[bool] = []
    for payload in drawn:
        if payload == b"":  # a cleared retained view: no zones, not a view to judge
            continue
        message = parsed(payload)
        if isinstance(message, dict):
            message["header"] = HEADER
        try:
            text = (
                payload.decode()
                if isinstance(message, NotJson)
                else json.dumps(message, allow_nan=False)
            )
        except (UnicodeDecodeError, ValueError):  # no UTF-8, or a NaN: no JSON at all
            text = "\ufffd"
        texts.append(text)
        expected.append(
            not isinstance(message, NotJson) and text != "\ufffd" and allowed("zones", message)
        )
    result = subprocess.run(
        ["node", "--input-type=module", "-e", JUDGE],
        cwd=DASHBOARD,
        input=json.dumps(texts),
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    verdicts = json.loads(result.stdout)
    wrong = [
        (text[:300], verdict)
        for text, verdict, ok in zip(texts, verdicts, expected, strict=True)
        if (verdict is True) != ok
    ]
    assert wrong == [], wrong[:5]
    kept = sum(expected)
    assert kept >= 20 and len(expected) - kept >= 20, f"{kept} of {len(expected)} kept"
