"""What a request's path, query and headers may hold, and times as the CLI takes them (pure).

A time is an ISO 8601 date-time with its zone (`2026-11-26T14:02:00Z`), a date (its midnight,
UTC), a span back from now (`90s`, `30m`, `24h`, `7d`) or `now`: `gridfleet job history`'s forms,
but a time with no zone is refused rather than read as the server's local time, which a caller
elsewhere cannot know.
"""

from __future__ import annotations

import re
from datetime import UTC, date, datetime, time, timedelta
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StringConstraints, WithJsonSchema

from gridfleet.protocol.messages import MAX_AUDIT_PAGE, MAX_HISTORY_PAGE, Cursor, Id, JobState

MAX_JOBS_PAGE = 500
# At most 99999 of a unit (273 years of days): a span always names a time that exists.
SPAN_PATTERN = r"^[0-9]{1,5}(\.[0-9]{1,6})?[smhd]$"
_SPAN = re.compile(SPAN_PATTERN)
_DATE_TIME = re.compile(
    r"^[0-9]{4}-[0-9]{2}-[0-9]{2}[Tt ][0-9]{2}:[0-9]{2}:[0-9]{2}(\.[0-9]{1,9})?([Zz]|[+-][0-9]{2}:[0-9]{2})$"
)
_DATE = re.compile(r"^[0-9]{4}-[0-9]{2}-[0-9]{2}$")
SPAN_S = {"s": 1, "m": 60, "h": 3600, "d": 86400}
MOMENT_WORDS = (
    "an ISO 8601 date-time with its zone (2026-11-26T14:02:00Z), a date (2026-11-26, its "
    "midnight UTC), a span back from now (90s, 30m, 24h, 7d) or now"
)


def at_moment(text: str, now: datetime) -> datetime:
    """The time `text` names (MOMENT_WORDS), aware; ValueError in words when it names none."""
    word = text.strip()
    try:
        if word == "now":
            return now
        span = _SPAN.fullmatch(word)
        if span is not None:
            return now - timedelta(seconds=float(word[:-1]) * SPAN_S[word[-1]])
        if _DATE.fullmatch(word):
            return datetime.combine(date.fromisoformat(word), time(), UTC)
        if _DATE_TIME.fullmatch(word):
            # Python reads neither a lowercase t/z nor more than 6 digits of a second.
            whole, _, rest = word.upper().replace(" ", "T").partition(".")
            if rest:
                digits = re.match(r"[0-9]*", rest)
                assert digits is not None
                whole += "." + digits.group(0)[:6].ljust(6, "0") + rest[len(digits.group(0)) :]
            return datetime.fromisoformat(whole)
    except (ValueError, OverflowError):
        raise ValueError(f"{text[:40]!r} is no time that exists: give {MOMENT_WORDS}") from None
    raise ValueError(f"{text[:40]!r} is not a time: give {MOMENT_WORDS}")


def _checked_moment(text: str) -> str:
    at_moment(text, datetime.now(UTC))
    return text


Moment = Annotated[
    str,
    AfterValidator(_checked_moment),
    WithJsonSchema(
        {
            "anyOf": [
                {"type": "string", "format": "date-time"},
                {"type": "string", "format": "date"},
                {"type": "string", "pattern": SPAN_PATTERN},
                {"const": "now"},
            ],
            "description": MOMENT_WORDS,
        }
    ),
]
Format = Literal["json", "csv"]
JobsCursor = Annotated[str, StringConstraints(pattern=r"^[0-9]{1,6}$")]
# Idempotency-Key: 1-200 printable ASCII characters (RFC 9110 field values, no spaces at the ends).
IdempotencyKey = Annotated[str, StringConstraints(pattern=r"^[!-~]([ -~]{0,198}[!-~])?$")]
EventId = Annotated[str, StringConstraints(max_length=64)]


class Params(BaseModel):
    """A query: exactly its parameters."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class Headers(BaseModel):
    """The headers a route reads (the others are none of its business)."""

    model_config = ConfigDict(extra="ignore", frozen=True, populate_by_name=True)


class JobsQuery(Params):
    """`GET /jobs`: which jobs of the view's listing, and a page of them."""

    state: JobState | None = None
    unit: Id | None = None
    limit: int = Field(100, ge=1, le=MAX_JOBS_PAGE)
    cursor: JobsCursor | None = None


class HistoryQuery(Params):
    """`GET /history`: the job history's range and filters, as `gridfleet job history`."""

    since: Moment = "24h"
    until: Moment | None = None
    unit: Id | None = None
    job: Id | None = None
    state: JobState | None = None
    format: Format = "json"
    limit: int = Field(200, ge=1, le=MAX_HISTORY_PAGE)
    cursor: Cursor | None = None


class ChargesQuery(Params):
    """`GET /history/charges`: the charges' range, as `gridfleet job history --charges`."""

    since: Moment = "24h"
    until: Moment | None = None
    unit: Id | None = None
    format: Format = "json"
    limit: int = Field(200, ge=1, le=MAX_HISTORY_PAGE)
    cursor: Cursor | None = None


class AuditQueryParams(Params):
    """`GET /audit`: the audit trail's range, as `gridfleet audit`."""

    since: Moment = "24h"
    until: Moment | None = None
    actor: Id | None = None
    format: Format = "json"
    limit: int = Field(100, ge=1, le=MAX_AUDIT_PAGE)
    cursor: Cursor | None = None


class ReleaseQuery(Params):
    """`DELETE /stop`: why it is released, one line."""

    reason: Annotated[str, StringConstraints(max_length=200, pattern=r"^[^\r\n\x00]*$")] = (
        "released over the API"
    )


class JobPath(BaseModel):
    """A job named in the path."""

    job_id: Id


class UnitPath(BaseModel):
    """A unit named in the path."""

    unit_id: Id


class ZonePath(BaseModel):
    """A zone named in the path."""

    name: Id


class SubmitHeaders(Headers):
    """`POST /jobs`: the caller's key for a request it may send again."""

    idempotency_key: IdempotencyKey | None = Field(
        None,
        alias="Idempotency-Key",
        description="1-200 printable characters: the same key again (with the same body) is the "
        "same job, never a second one",
    )


class EventsHeaders(Headers):
    """`GET /events`: where a stream that broke goes on from."""

    last_event_id: EventId | None = Field(
        None, alias="Last-Event-ID", description="the id of the last event a stream received"
    )
