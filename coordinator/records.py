"""The records the coordinator answers pages of: the audit (protocol.md §6.8) and the job history
(§6.10), one way for both.

Every query reaches the core like any request. The core checks it (who may read it, and its
range by the one rule of `range_problem`) and refuses it in words, or hands it on as a checked
`RecordQuery` in its Effects; the shell answers each from the store of its kind, a `RecordsDesk`
(`answer`), a page at a time by the one paging rule of `page_of`. Pure: no store is opened here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING, Literal, Protocol, TypeVar

from gridfleet.protocol.messages import (
    AuditEntry,
    AuditQuery,
    ChargeEntry,
    JobHistoryEntry,
    JobHistoryQuery,
)

if TYPE_CHECKING:  # effects.py imports this module
    from gridfleet.coordinator.effects import Messages
    from gridfleet.outbound import Outbound

RecordKind = Literal["audit", "job_history"]  # each a request kind and a store
Query = AuditQuery | JobHistoryQuery
Entry = AuditEntry | JobHistoryEntry | ChargeEntry  # charges: a history query of kind "charges"
E = TypeVar("E", bound=Entry)
E_co = TypeVar("E_co", bound=Entry, covariant=True)
MAX_RANGE = timedelta(days=3660)  # ten years: anything longer is a mistake in the dates


def as_utc(moment: datetime) -> datetime:
    """`moment` in UTC; a time without a zone is read as UTC (every timestamp is, §1)."""
    return moment.replace(tzinfo=UTC) if moment.tzinfo is None else moment.astimezone(UTC)


def _iso(at: datetime) -> str:
    return at.isoformat().replace("+00:00", "Z")


def range_problem(since: datetime, until: datetime | None, now: datetime) -> str | None:
    """Why a query's range is refused, in one line (None: it is answered): the records' one rule.

    `until` null is now; a time without a zone is UTC; `since` must lie before `until` (an empty
    or backwards range holds nothing) and at most ten years before it.
    """
    start, end = as_utc(since), as_utc(until if until is not None else now)
    if start >= end:
        return f"since {_iso(start)} is not before until {_iso(end)}"
    if end - start > MAX_RANGE:
        return f"since {_iso(start)} to until {_iso(end)} spans more than ten years"
    return None


@dataclass(frozen=True)
class RecordQuery:
    """A query the core checked, its range resolved: the shell answers it from its kind's store."""

    kind: RecordKind
    query: Query
    since: float  # epoch seconds: entries at or after this
    until: float  # and before this

    @classmethod
    def of(cls, kind: RecordKind, query: Query, now: datetime) -> RecordQuery:
        """`query` (its range checked already) with `until` null read as `now`."""
        until = query.until if query.until is not None else now
        return cls(kind, query, as_utc(query.since).timestamp(), as_utc(until).timestamp())

    @property
    def after(self) -> int | None:
        """The row the previous page ended on (its `next_cursor`), None for the first page."""
        return int(self.query.cursor) if self.query.cursor is not None else None


class RecordsDesk(Protocol[E_co]):
    """A store the shell answers record queries from (AuditStore, HistoryStore)."""

    def rows(self, query: RecordQuery, limit: int) -> Sequence[tuple[int, E_co]]:
        """Up to `limit` entries of `query` after its cursor, in page order, with their row ids."""
        ...


def page_of(desk: RecordsDesk[E], query: RecordQuery) -> tuple[list[E], str | None]:
    """One page of `query` from `desk` and the next page's cursor (None: the last page).

    The records' one paging rule: one row more than the limit is read, to know whether there is
    a next page without a second query; the cursor is the last shown row's id.
    """
    rows = desk.rows(query, query.query.limit + 1)
    shown = rows[: query.query.limit]
    cursor = str(shown[-1][0]) if len(rows) > query.query.limit else None
    return [entry for _, entry in shown], cursor


def answer(record: RecordQuery, desk: RecordsDesk[Entry], say: Messages) -> Outbound | None:
    """The page answering `record` from `desk` (None: its query said nowhere to reply)."""
    query = record.query
    if query.reply_to is None:
        return None  # (the core hands on only queries with somewhere to reply)
    entries, cursor = page_of(desk, record)
    return say.page(record.kind, query.reply_to, query.request_id, entries, cursor)
