"""`/history`, `/history/charges` and `/audit`: the coordinator's records, a page at a time,
as JSON or as the CLI's CSV; the next page's address in a `Link` header (rel="next")."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any
from urllib.parse import urlencode

from flask import Response, request

from gridfleet.dashboard.api.context import caller, current
from gridfleet.dashboard.api.csv_out import (
    CSV_MEDIA,
    audit_csv,
    charges_csv,
    csv_answer,
    history_csv,
)
from gridfleet.dashboard.api.fleet import FleetView
from gridfleet.dashboard.api.models import AuditList, ChargesPage, HistoryPage
from gridfleet.dashboard.api.params import (
    AuditQueryParams,
    ChargesQuery,
    HistoryQuery,
    at_moment,
)
from gridfleet.dashboard.api.problems import ApiProblem, refusal
from gridfleet.dashboard.api.web import also, answer, blueprint
from gridfleet.protocol.messages import AuditPage, JobHistoryPage, Reply

api = blueprint("records", "the job history, the charges and the audit trail")


def both(model: str) -> dict[str, Any]:
    """A 200 answered as JSON (`model`) or CSV (`format=csv`)."""
    return {
        "description": f"a page: JSON ({model}), or CSV with format=csv",
        "content": {
            "application/json": {"schema": {"$ref": f"#/components/schemas/{model}"}},
            CSV_MEDIA: {"schema": {"type": "string"}},
        },
    }


def span(since: str, until: str | None) -> tuple[datetime, datetime | None]:
    """The range a query names, read now (400 for a time that is none)."""
    now = datetime.now(UTC)
    try:
        return at_moment(since, now), None if until is None else at_moment(until, now)
    except ValueError as exc:
        raise ApiProblem("bad_request", str(exc)) from None


def next_link(cursor: str | None) -> dict[str, str]:
    """The Link header of the next page (none on the last)."""
    if cursor is None:
        return {}
    args = {**request.args.to_dict(), "cursor": cursor}
    return {"Link": f'<{request.path}?{urlencode(args)}>; rel="next"'}


def accepted_page(page: JobHistoryPage | AuditPage | Reply) -> JobHistoryPage | AuditPage:
    """The page, or the coordinator's refusal as a problem (its reason kept)."""
    if isinstance(page, Reply):
        raise refusal(page.code, page.reason)
    if not page.accepted:
        raise ApiProblem("invalid", page.reason or "refused by the coordinator")
    return page


@api.get(
    "/history",
    summary="The job history: every change of every job",
    responses={200: both("HistoryPage"), **also(422)},
)
def job_history(query: HistoryQuery) -> Response:
    """The range and filters of `gridfleet job history`; CSV in its columns."""
    who = caller("audit")
    config = current().config
    since, until = span(query.since, query.until)

    async def work(view: FleetView) -> JobHistoryPage | AuditPage:
        return accepted_page(
            await view.job_history(
                config.request_s,
                since=since,
                until=until,
                unit=query.unit,
                job_id=query.job,
                state=query.state,
                limit=query.limit,
                cursor=query.cursor,
            )
        )

    page = current().run(who, work, online=True)
    assert isinstance(page, JobHistoryPage)
    link = next_link(page.next_cursor)
    if query.format == "csv":
        return csv_answer(history_csv(page.entries), "job-history.csv", link)
    return answer(HistoryPage(entries=page.entries, next_cursor=page.next_cursor), headers=link)


@api.get(
    "/history/charges",
    summary="The charges' starts and ends",
    responses={200: both("ChargesPage"), **also(422)},
)
def charge_history(query: ChargesQuery) -> Response:
    """The range of `gridfleet job history --charges`; CSV in its columns."""
    who = caller("audit")
    config = current().config
    since, until = span(query.since, query.until)

    async def work(view: FleetView) -> JobHistoryPage | AuditPage:
        return accepted_page(
            await view.job_history(
                config.request_s,
                kind="charges",
                since=since,
                until=until,
                unit=query.unit,
                limit=query.limit,
                cursor=query.cursor,
            )
        )

    page = current().run(who, work, online=True)
    assert isinstance(page, JobHistoryPage)
    link = next_link(page.next_cursor)
    if query.format == "csv":
        return csv_answer(charges_csv(page.charges), "charges.csv", link)
    return answer(ChargesPage(charges=page.charges, next_cursor=page.next_cursor), headers=link)


@api.get(
    "/audit",
    summary="The audit trail: who did what, and when (operator and dashboard accounts)",
    responses={200: both("AuditList"), **also(422)},
)
def audit_trail(query: AuditQueryParams) -> Response:
    """The range of `gridfleet audit`; CSV in its columns."""
    who = caller("audit")
    config = current().config
    since, until = span(query.since, query.until)

    async def work(view: FleetView) -> JobHistoryPage | AuditPage:
        return accepted_page(
            await view.audit(
                config.request_s,
                since=since,
                until=until,
                actor=query.actor,
                limit=query.limit,
                cursor=query.cursor,
            )
        )

    page = current().run(who, work, online=True)
    assert isinstance(page, AuditPage)
    link = next_link(page.next_cursor)
    if query.format == "csv":
        return csv_answer(audit_csv(page.entries), "audit.csv", link)
    return answer(AuditList(entries=page.entries, next_cursor=page.next_cursor), headers=link)
