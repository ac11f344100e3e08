"""The page tells the day (issue 35): the History view with its filters, durations, pages and a
CSV download read back; the Audit tab; alerts as notifications that stay until acknowledged; the
throughput chart's day, from the job history. Real Chromium; the real coordinator, units and
alerts process answer, but for the paging test, where the test plays the coordinator to hand the
page pages of its own making.

`GRIDFLEET_REFRESH_DOCS=1 .venv/bin/pytest tests/dashboard/test_dashboard_history_browser.py -k screenshot`
also copies the live screenshots to docs/dashboard-history.png and docs/dashboard-alerts.png.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import shutil
import subprocess
from collections.abc import Callable, Iterator
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import expect

from gridfleet.alerts.settings import AlertSettings
from gridfleet.alerts.shell import AlertsShell
from gridfleet.console.job import CHARGE_COLUMNS, HISTORY_COLUMNS
from gridfleet.protocol import Topics, encode
from gridfleet.protocol.messages import ChargeEntry, JobHistoryEntry, JobHistoryPage
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.browser import OpenDashboard
from support.cli import gridfleet
from support.paths import REPO
from support.probe import MqttProbe
from support.wait import wait_for

pytestmark = pytest.mark.browser

PLAYFIELD = REPO / "maps" / "playfield.toml"
DOCS = REPO / "docs"
# Only the stop's rule: the others (the coordinator's absence above all) stay quiet in a test.
STOP_ONLY = AlertSettings(
    unit_lost_s=None,
    unit_stuck_s=None,
    job_queued_s=None,
    step_rate_below=None,
    coordinator_down_s=None,
    broker_down_s=None,
)


@contextlib.contextmanager
def alerts_process(
    url: str, topics: Topics, settings: AlertSettings = STOP_ONLY
) -> Iterator[ServiceThread[AlertsShell]]:
    """The real alerts process (`gridfleet alerts`) on the test's broker and root."""

    def make() -> AlertsShell:
        return AlertsShell(url, settings, root=topics.root, tick_s=0.05)

    with ServiceThread(make, "alerts") as running:
        yield running


def gridfleet_job(broker: BrokerThread, root: str, *args: str) -> subprocess.CompletedProcess[str]:
    """`gridfleet job ARGS` against the test's broker, in a process of its own."""
    return gridfleet("job", *args, "--broker", broker.url, "--root", root, timeout=90)


def same_cell(a: str, b: str) -> bool:
    """Two CSV cells alike; numbers by value (JSON keeps no `80.0`: the page writes `80`)."""
    if a == b:
        return True
    try:
        return float(a) == float(b)
    except ValueError:
        return False


def download_csv(dash: OpenDashboard) -> tuple[str, list[dict[str, str]], list[str]]:
    """Press "download CSV"; the file's name, its rows and its header, as the browser saved it."""
    with dash.page.expect_download() as info:
        dash.page.locator("#history-csv").click()
    download = info.value
    text = Path(download.path()).read_text(encoding="utf-8")
    reader = csv.DictReader(io.StringIO(text))
    rows = list(reader)
    return download.suggested_filename, rows, list(reader.fieldnames or [])


def queue_and_finish(
    dash: OpenDashboard, jobs: dict[str, tuple[tuple[int, int], tuple[int, int]]]
) -> None:
    """Queue jobs with the page's form, each accepted, and wait until the fleet has done them."""
    for job_id, (pickup, dropoff) in jobs.items():
        dash.submit_job(pickup, dropoff, 1.5, job_id=job_id)
        expect(dash.page.locator("#job-feedback")).to_contain_text(f": accepted (job {job_id})")
    for job_id in jobs:
        done = dash.page.locator(f"#finished tr[data-job='{job_id}'] .state")
        expect(done).to_have_text("done", timeout=90_000)


def history_rows(dash: OpenDashboard) -> list[dict[str, str]]:
    """The History table as shown: each row's cells by class."""
    rows: list[dict[str, str]] = dash.page.evaluate(
        """() => [...document.querySelectorAll('#history tbody tr')].map((tr) =>
            Object.fromEntries([...tr.children].map((td) => [td.classList[0], td.textContent])))"""
    )
    return rows


def open_tab(dash: OpenDashboard, name: str) -> None:
    dash.page.locator(f"#tabs [data-tab={name}]").click()
    expect(dash.page.locator(f"#{name}-panel")).to_be_visible()


@pytest.mark.slow  # the whole system, end to end
def test_the_history_view_shows_the_fleets_jobs_and_its_csv_is_the_commands(
    broker: BrokerThread,
    root: str,
    run_system: Callable[..., Any],
    open_dashboard: Callable[..., OpenDashboard],
) -> None:
    run_system(PLAYFIELD)
    dash = open_dashboard()
    expect(dash.page.locator("#coord")).to_contain_text("coordinator: online")
    queue_and_finish(dash, {"crate-1": ((1, 8), (8, 8)), "crate-2": ((0, 0), (9, 9))})

    # The view asks for the last day when first opened: both jobs' lives, queued to done.
    open_tab(dash, "history")
    table = dash.page.locator("#history")
    expect(table).to_have_attribute("data-state", "complete")
    rows = history_rows(dash)
    for job_id in ("crate-1", "crate-2"):
        states = [r["state"] for r in rows if r["job"] == job_id]
        assert states[0] == "queued" and states[-1] == "done", states
    # A final state shows the job's whole duration; the summary counts the jobs that ended.
    done = {r["job"]: r for r in rows if r["state"] == "done"}
    assert set(done) == {"crate-1", "crate-2"}
    summary = dash.page.locator("#history-summary")
    expect(summary).to_contain_text("jobs ended: done 2")
    expect(summary).to_contain_text("(median)")

    # The CSV is the whole of it, in the command's columns, and reads back as the command's own.
    name, page_csv, header = download_csv(dash)
    assert header == list(HISTORY_COLUMNS)
    assert name.startswith("gridfleet-history-") and name.endswith(".csv")
    expect(dash.page.locator("#history-feedback")).to_contain_text(f"{len(page_csv)} changes saved")
    assert [r["job"] for r in page_csv] == [r["job"] for r in rows]
    since = page_csv[0]["at"]
    command = gridfleet_job(broker, root, "history", "--since", since, "--csv")
    assert command.returncode == 0, command.stderr
    command_csv = list(csv.DictReader(io.StringIO(command.stdout)))
    assert len(command_csv) == len(page_csv)
    for ours, theirs in zip(page_csv, command_csv, strict=True):
        assert all(same_cell(ours[k], theirs[k]) for k in HISTORY_COLUMNS), (ours, theirs)
    # The table's duration is the CSV's `since_submitted_s` of the job's done entry.
    took = {r["job"]: float(r["since_submitted_s"]) for r in page_csv if r["state"] == "done"}
    for job_id, seconds in took.items():
        assert seconds > 0
        assert done[job_id]["took"] == f"{round(seconds, 1):g} s" or "min" in done[job_id]["took"]

    # Filters: the done changes alone; one unit's; a unit with none says so.
    form = dash.page.locator("#history-form")
    form.locator("select[name=state]").select_option("done")
    form.locator("button[type=submit]").click()
    expect(table).to_have_attribute("data-rows", "2")
    assert {r["state"] for r in history_rows(dash)} == {"done"}
    unit = page_csv[-1]["unit"]
    form.locator("input[name=unit]").fill(unit)
    form.locator("button[type=submit]").click()
    expect(table).to_have_attribute("data-state", "complete")
    assert {r["unit"] for r in history_rows(dash)} == {unit}
    form.locator("input[name=unit]").fill("nobody")
    form.locator("button[type=submit]").click()
    expect(table).to_have_attribute("data-rows", "0")
    expect(summary).to_have_text("no change in this range")

    # Bad input: a range backwards is told at once and nothing is asked; a bad unit name too.
    form.locator("input[name=unit]").fill("")
    form.locator("input[name=since]").fill("2026-11-27T10:00")
    form.locator("input[name=until]").fill("2026-11-26T10:00")
    form.locator("button[type=submit]").click()
    feedback = dash.page.locator("#history-feedback")
    expect(feedback).to_have_text("since 2026-11-27T10:00 is not before until 2026-11-26T10:00")
    form.locator("input[name=until]").fill("")
    form.locator("input[name=unit]").fill("no such unit")
    form.locator("button[type=submit]").click()
    expect(feedback).to_contain_text('unit "no such unit": letters, digits')
    # What only the coordinator can judge (a range of more than ten years) comes back in words.
    form.locator("input[name=unit]").fill("")
    form.locator("input[name=since]").fill("2001-01-01T00:00")
    form.locator("button[type=submit]").click()
    expect(feedback).to_contain_text("job history: refused — ")
    expect(table).to_have_attribute("data-state", "refused")

    # The day's chart reads the history: a page opened now counts both jobs in this hour.
    dash.page.reload()
    dash.wait_connected()
    chart = dash.page.locator("#day-chart")
    expect(chart).to_have_attribute("data-per-hour", " ".join(["0"] * 23 + ["2"]))
    assert not dash.errors


def entry(job: str, minute: int, state: str = "queued") -> JobHistoryEntry:
    """A made-up history entry of job `job`, `minute` minutes into a day."""
    at = datetime(2026, 11, 26, 8, 0, tzinfo=UTC) + timedelta(minutes=minute)
    return JobHistoryEntry.model_validate(
        {
            "at": at, "job": job, "state": state, "unit": "unit1", "since_submitted_s": 0.0,
            "pickup": [1, 1], "dropoff": [8, 8], "mass_kg": 1.5, "submitted_by": "dash-test",
            "reason": 'a "quoted", reason' if state == "done" else None,
        }
    )  # fmt: skip


def test_the_history_pages_through_the_cursor_and_the_csv_takes_every_page(
    open_dashboard: Callable[..., OpenDashboard],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
) -> None:
    probe = probe_factory()
    asked = topics.request("job_history")
    probe.subscribe(asked)
    dash = open_dashboard()

    def answer(
        cursor: str | None, entries: list[JobHistoryEntry], next_cursor: str | None
    ) -> dict[str, Any]:
        """Wait for the page's history request at `cursor` (not the day chart's); answer it."""

        def ours() -> dict[str, Any] | None:
            for seen in probe.received(asked):
                query = json.loads(seen.payload)
                if query["state"] is None and query["cursor"] == cursor:
                    return dict(query)
            return None

        query = wait_for(ours, 20.0, what=f"the history request at cursor {cursor}")
        page = JobHistoryPage.model_validate(
            {"header": {"version": "1.6", "seq": 0, "timestamp": datetime.now(UTC), "sender": "coordinator"},
             "request_id": query["request_id"], "accepted": True, "entries": entries,
             "next_cursor": next_cursor}
        )  # fmt: skip
        probe.publish(topics.history_reply(dash.client_id), encode(page))
        return query

    open_tab(dash, "history")
    first = answer(None, [entry("j1", 0), entry("j1", 1, "to_pickup"), entry("j1", 2, "done")], "3")
    table = dash.page.locator("#history")
    expect(table).to_have_attribute("data-rows", "3")
    more = dash.page.locator("#history-more")
    expect(more).to_be_visible()
    more.click()
    second = answer("3", [entry("j2", 3), entry("j2", 4, "cancelled")], "5")
    # The next page is the same query, on from the cursor.
    assert {k: v for k, v in second.items() if k not in ("cursor", "header", "request_id")} == {
        k: v for k, v in first.items() if k not in ("cursor", "header", "request_id")
    }
    expect(table).to_have_attribute("data-rows", "5")
    # The download fetches the pages not loaded yet, the most at a time, and saves them all.
    with dash.page.expect_download() as info:
        dash.page.locator("#history-csv").click()
        third = answer("5", [entry("j3", 5)], None)
    assert third["limit"] == 1000
    rows = list(csv.DictReader(io.StringIO(Path(info.value.path()).read_text(encoding="utf-8"))))
    assert [(r["job"], r["state"]) for r in rows] == [
        ("j1", "queued"), ("j1", "to_pickup"), ("j1", "done"), ("j2", "queued"),
        ("j2", "cancelled"), ("j3", "queued"),
    ]  # fmt: skip
    assert rows[2]["reason"] == 'a "quoted", reason'  # quoted as the csv module reads it
    assert rows[0]["at"] == "2026-11-26T08:00:00.000Z"  # as the command writes it
    expect(more).to_be_hidden()
    expect(table).to_have_attribute("data-rows", "6")
    assert not dash.errors


def charge(unit: str, minute: int, event: str, pct: float) -> dict[str, Any]:
    """A made-up charge entry (as JSON), `minute` minutes into a day, checked by the model."""
    at = datetime(2026, 11, 26, 8, 0, tzinfo=UTC) + timedelta(minutes=minute)
    entry = {"at": at, "unit": unit, "charger": "C1", "event": event, "battery_pct": pct,
             "reason": f"test {event}"}  # fmt: skip
    return ChargeEntry.model_validate(entry).model_dump(mode="json")


def test_the_history_shows_the_charges_checked_entry_by_entry_page_by_page(
    open_dashboard: Callable[..., OpenDashboard],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
) -> None:
    probe = probe_factory()
    asked = topics.request("job_history")
    probe.subscribe(asked)
    dash = open_dashboard()
    answered: set[str] = set()

    def answer(
        kind: str, cursor: str | None, key: str, entries: list[Any], more: str | None
    ) -> Any:
        """Wait for the page's next history request of `kind` at `cursor`; answer with `entries`."""

        def ours() -> dict[str, Any] | None:
            for seen in probe.received(asked):
                query = json.loads(seen.payload)
                new = query["request_id"] not in answered and query["state"] is None
                if new and query.get("kind") == kind and query["cursor"] == cursor:
                    answered.add(query["request_id"])
                    return dict(query)
            return None

        query = wait_for(ours, 20.0, what=f"the {kind} history request at cursor {cursor}")
        page = json.loads(encode(JobHistoryPage.model_validate(
            {"header": {"version": "1.6", "seq": 0, "timestamp": datetime.now(UTC), "sender": "coordinator"},
             "request_id": query["request_id"], "accepted": True, "next_cursor": more}
        )))  # fmt: skip
        page[key] = entries  # as given: a bad entry too, as a faulty coordinator might send it
        probe.publish(topics.history_reply(dash.client_id), json.dumps(page).encode())
        return query

    open_tab(dash, "history")
    answer("jobs", None, "entries", [entry("j1", 0).model_dump(mode="json")], None)
    table = dash.page.locator("#history")
    expect(table).to_have_attribute("data-rows", "1")
    form = dash.page.locator("#history-form")
    job, state = form.locator("input[name=job]"), form.locator("select[name=state]")
    expect(job).to_be_enabled()
    # The switch asks for the charges at once: the unit filter applies, the jobs' filters do not.
    form.locator("input[name=unit]").fill("u03")
    job.fill("j1")
    form.locator("select[name=kind]").select_option("charges")
    expect(job).to_be_disabled()
    expect(state).to_be_disabled()
    bad = {**charge("u03", 1, "ended", 50.0), "battery_pct": 250}
    first = answer("charges", None, "charges",
                   [charge("u03", 0, "started", 35.0), bad, charge("u03", 2, "ended", 82.5)], "3")  # fmt: skip
    assert (first["unit"], first["job_id"], first["state"]) == ("u03", None, None)
    expect(table).to_have_attribute("data-rows", "2")
    expect(table).to_have_attribute("data-dropped", "1")
    expect(dash.page.locator("#history-feedback")).to_contain_text("left out 1 malformed entry")
    expect(dash.page.locator("#history thead tr[data-kind=charges]")).to_be_visible()
    expect(dash.page.locator("#history thead tr[data-kind=jobs]")).to_be_hidden()
    rows = history_rows(dash)
    assert [(r["charger"], r["event"], r["battery"]) for r in rows] == [
        ("C1", "started", "35.0 %"), ("C1", "ended", "82.5 %"),
    ]  # fmt: skip
    expect(dash.page.locator("#history-summary")).to_contain_text("2 charge entries (more to load)")
    # The CSV fetches the remaining pages and has the command's charge columns.
    with dash.page.expect_download() as info:
        dash.page.locator("#history-csv").click()
        third = answer("charges", "3", "charges", [charge("u03", 5, "started", 20.0)], None)
    assert third["limit"] == 1000
    assert info.value.suggested_filename.startswith("gridfleet-charges-")
    reader = csv.DictReader(io.StringIO(Path(info.value.path()).read_text(encoding="utf-8")))
    got = list(reader)
    assert list(reader.fieldnames or []) == list(CHARGE_COLUMNS)
    assert [(r["event"], float(r["battery_pct"])) for r in got] == [
        ("started", 35.0), ("ended", 82.5), ("started", 20.0),
    ]  # fmt: skip
    assert got[0]["at"] == "2026-11-26T08:00:00.000Z"
    expect(table).to_have_attribute("data-rows", "3")
    # Back to the jobs: their filters again, their header.
    form.locator("select[name=kind]").select_option("jobs")
    expect(job).to_be_enabled()
    again = answer("jobs", None, "entries", [], None)
    assert (again["unit"], again["job_id"]) == ("u03", "j1")
    expect(table).to_have_attribute("data-rows", "0")
    expect(dash.page.locator("#history thead tr[data-kind=jobs]")).to_be_visible()
    assert not dash.errors


def test_an_alert_stays_on_the_page_until_acknowledged_even_once_cleared(
    broker: BrokerThread,
    topics: Topics,
    open_dashboard: Callable[..., OpenDashboard],
) -> None:
    with alerts_process(broker.url, topics):
        dash = open_dashboard()
        toasts = dash.page.locator("#toast-list .toast")
        expect(toasts).to_have_count(0)
        dash.press_stop()  # the stop's rule raises an alert at once
        expect(toasts).to_have_count(1)
        toast = toasts.first
        expect(toast).to_contain_text("emergency stop")
        expect(toast).to_contain_text("in force")
        expect(dash.page.locator("#alerts-count")).to_have_text("1")
        dash.hold_release()
        # Cleared, and still there: nobody has said they saw it.
        expect(toast).to_contain_text("cleared")
        expect(toasts).to_have_count(1)
        toast.get_by_role("button", name="Acknowledge").click()
        expect(toasts).to_have_count(0)
        expect(dash.page.locator("#alerts-count")).to_have_text("")
        expect(dash.page.locator("#alerts-feedback")).to_contain_text(": accepted")
        # The Alerts tab lists it, acknowledged by this page's sender (no accounts: as given).
        open_tab(dash, "alerts")
        row = dash.page.locator("#alerts-cleared tbody tr[data-alert]").first
        expect(row.locator(".acked")).to_contain_text(dash.client_id)
        expect(row.locator("button")).to_have_count(0)
        # A reload shows nothing acknowledged again: the view is retained, the ack is in it.
        dash.page.reload()
        dash.wait_connected()
        expect(dash.page.locator("#alerts-cleared tbody tr[data-alert]")).to_have_count(1)
        expect(toasts).to_have_count(0)
        assert not dash.errors


def test_the_audit_tab_shows_what_this_page_did(
    run_system: Callable[..., Any],
    open_dashboard: Callable[..., OpenDashboard],
) -> None:
    run_system(PLAYFIELD)
    dash = open_dashboard()
    expect(dash.page.locator("#coord")).to_contain_text("coordinator: online")
    dash.submit_job((1, 8), (8, 8), 1.5, job_id="audited")
    expect(dash.page.locator("#job-feedback")).to_contain_text(": accepted (job audited)")
    # Without accounts anybody may read the audit (protocol.md §6.8): the tab is offered.
    open_tab(dash, "audit")
    audit = dash.page.locator("#audit")
    expect(audit).to_have_attribute("data-state", "complete")
    row = dash.page.locator("#audit tbody tr[data-act=submit_job]").filter(has_text="audited")
    expect(row).to_have_count(1)
    # Nobody vouched for the sender without accounts: its name is what it claimed, marked "?".
    expect(row.locator(".actor")).to_have_text(f"{dash.client_id}?")
    expect(row.locator(".outcome")).to_have_text("accepted")
    form = dash.page.locator("#audit-form")
    form.locator("input[name=actor]").fill("bad name")
    form.locator("button[type=submit]").click()
    expect(dash.page.locator("#audit-feedback")).to_contain_text(
        'account "bad name": letters, digits'
    )
    assert not dash.errors


@pytest.mark.slow
def test_screenshot_of_the_history_and_the_alerts_on_the_live_playfield(
    broker: BrokerThread,
    topics: Topics,
    run_system: Callable[..., Any],
    open_dashboard: Callable[..., OpenDashboard],
) -> None:
    run_system(PLAYFIELD, step_s=0.1)
    # The stop, and a job queued for more than 2 s: one alert cleared, one in force.
    with alerts_process(broker.url, topics, replace(STOP_ONLY, job_queued_s=2.0)):
        dash = open_dashboard()
        expect(dash.page.locator("#coord")).to_contain_text("coordinator: online")
        queue_and_finish(dash, {"crate-1": ((1, 8), (8, 8)), "crate-2": ((0, 0), (9, 9))})
        dash.submit_job((9, 0), (0, 9), 1.5, job_id="crate-3")
        open_tab(dash, "history")
        expect(dash.page.locator("#history")).to_have_attribute("data-state", "complete")
        history = dash.screenshot("dashboard-history")
        dash.press_stop()
        toasts = dash.page.locator("#toast-list .toast")
        expect(toasts).to_have_count(1)
        dash.hold_release()
        expect(toasts.first).to_contain_text("cleared")
        # Only unit4 carries 15 kg, and it is out of service: the job waits, and is told.
        open_tab(dash, "fleet")
        dash.page.locator("#units tr[data-unit=unit4] button[data-command=out_of_service]").click()
        expect(dash.page.locator("#units tr[data-unit=unit4] .status")).to_contain_text(
            "out of service"
        )
        dash.submit_job((1, 1), (8, 1), 15.0, job_id="crate-4")
        expect(toasts).to_have_count(2)
        open_tab(dash, "alerts")
        alerts = dash.screenshot("dashboard-alerts")
        # The day's chart beside them (test-artifacts/ only): this hour's bar holds the done jobs.
        open_tab(dash, "fleet")
        dash.page.locator("#day-chart").scroll_into_view_if_needed()
        dash.screenshot("dashboard-throughput")
        assert not dash.errors
    if os.environ.get("GRIDFLEET_REFRESH_DOCS") == "1":
        shutil.copyfile(history, DOCS / "dashboard-history.png")
        shutil.copyfile(alerts, DOCS / "dashboard-alerts.png")
