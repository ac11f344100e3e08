"""`/history`, `/history/charges` and `/audit`: the coordinator's records, a page at a time,
as JSON or as the CLI's CSV; the next page's address in a `Link` header (rel="next")."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from datetime import UTC, datetime
from typing import Any, TypeAlias
from urllib.parse import urlencode

from flask import Response, request
from pydantic import BaseModel

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
from gridfleet.dashboard.api.problems import ApiProblem, P, accepted_page
from gridfleet.dashboard.api.web import also, answer, blueprint
from gridfleet.protocol.messages import Reply

api = blueprint("records", "the job history, the charges and the audit trail")
RecordQuery: TypeAlias = HistoryQuery | ChargesQuery | AuditQueryParams


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


def record_page(
    query: RecordQuery,
    ask: Callable[..., Awaitable[P | Reply]],
    filters: dict[str, object],
    shown: Callable[[P], BaseModel],
    csv: Callable[[P], str],
    filename: str,
) -> Response:
    """One page of a record, for an account that may read them: `ask` (a FleetView method) with
    the query's range, page and `filters`; JSON as `shown`, or `csv` as `filename`; the Link."""
    who = caller("audit")
    config = current().config
    since, until = span(query.since, query.until)

    async def work(view: FleetView) -> P:
        page = await ask(
            view,
            config.request_s,
            since=since,
            until=until,
            limit=query.limit,
            cursor=query.cursor,
            **filters,
        )
        return accepted_page(page)

    page = current().run(who, work, online=True)
    link = next_link(page.next_cursor)
    if query.format == "csv":
        return csv_answer(csv(page), filename, link)
    return answer(shown(page), headers=link)


@api.get(
    "/history",
    summary="The job history: every change of every job",
    responses={200: both("HistoryPage"), **also(422)},
)
def job_history(query: HistoryQuery) -> Response:
    """The range and filters of `gridfleet job history`; CSV in its columns."""
    return record_page(
        query,
        FleetView.job_history,
        {"unit": query.unit, "job_id": query.job, "state": query.state},
        lambda page: HistoryPage(entries=page.entries, next_cursor=page.next_cursor),
        lambda page: history_csv(page.entries),
        "job-history.csv",
    )


@api.get(
    "/history/charges",
    summary="The charges' starts and ends",
    responses={200: both("ChargesPage"), **also(422)},
)
def charge_history(query: ChargesQuery) -> Response:
    """The range of `gridfleet job history --charges`; CSV in its columns."""
    return record_page(
        query,
        FleetView.job_history,
        {"kind": "charges", "unit": query.unit},
        lambda page: ChargesPage(charges=page.charges, next_cursor=page.next_cursor),
        lambda page: charges_csv(page.charges),
        "charges.csv",
    )


@api.get(
    "/audit",
    summary="The audit trail: who did what, and when (operator and dashboard accounts)",
    responses={200: both("AuditList"), **also(422)},
)
def audit_trail(query: AuditQueryParams) -> Response:
    """The range of `gridfleet audit`; CSV in its columns."""
    return record_page(
        query,
        FleetView.audit,
        {"actor": query.actor},
        lambda page: AuditList(entries=page.entries, next_cursor=page.next_cursor),
        lambda page: audit_csv(page.entries),
        "audit.csv",
    )
