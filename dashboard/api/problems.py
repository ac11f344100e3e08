"""RFC 9457 problem details: the API's one shape of error, and the HTTP status of each code.

Every refusal is `application/problem+json`, `type` `urn:gridfleet:problem:<code>`. A refusal
of the coordinator keeps its words: `detail` is its `Reply.reason` verbatim (what `gridfleet
job` prints) and its `Reply.code` picks the status (STATUS_OF_CODE).
"""

from __future__ import annotations

from typing import TypeVar

from flask import Response
from flask_openapi3.types import ResponseDict
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from gridfleet.protocol.messages import Page, Reply

PROBLEM_MEDIA = "application/problem+json"
TYPE_PREFIX = "urn:gridfleet:problem:"
RETRY_S = 5  # Retry-After of a 503: the coordinator restarts, or its reply comes, within it

# The coordinator's refusal codes (protocol.md §6.5) and the API's own, with their statuses.
STATUS_OF_CODE: dict[str, int] = {
    # the coordinator's
    "invalid": 422,
    "bad_square": 422,
    "unknown_place": 422,
    "unknown_job": 404,
    "unknown_unit": 404,
    "unknown_zone": 404,
    "too_heavy": 422,
    "unreachable": 422,
    "zone_closed": 409,
    "conflict": 409,
    "queue_full": 429,
    "too_many": 429,
    "forbidden": 403,
    # the API's
    "bad_request": 400,  # not the schema: a body, a query, a path or a header
    "not_json": 400,  # a body that is not JSON
    "unauthorized": 401,  # no token, or no logged-in page for a read
    "wrong_token": 401,
    "role": 403,  # the account's role may not do this
    "cross_site": 403,  # another site's page, in a browser
    "not_found": 404,  # no such path, or no such job, unit or zone in the path
    "method_not_allowed": 405,
    "not_acceptable": 406,
    "payload_too_large": 413,
    "idempotency_key_reused": 422,  # the same key with another body
    "throttled": 429,  # too many wrong tokens from this address
    "too_many_streams": 429,  # every event stream is taken
    "not_online": 503,  # no coordinator online
    "no_reply": 503,  # the coordinator did not answer in time
    "no_broker": 503,  # the API cannot reach the broker as this account
    "internal": 500,  # a bug: said in one line, the rest in the dashboard's log
}
TITLES: dict[int, str] = {
    400: "Bad Request",
    401: "Unauthorized",
    403: "Forbidden",
    404: "Not Found",
    405: "Method Not Allowed",
    406: "Not Acceptable",
    409: "Conflict",
    413: "Content Too Large",
    422: "Unprocessable Content",
    429: "Too Many Requests",
    500: "Internal Server Error",
    503: "Service Unavailable",
}
# A refusal whose reply carries no code (a coordinator older than protocol 1.6).
UNCODED = "invalid"
P = TypeVar("P", bound=Page)


class FieldError(BaseModel):
    """One part of a request that is not as the document says: where, and what is wrong."""

    model_config = ConfigDict(extra="forbid")

    loc: list[str | int]
    msg: str
    type: str


class Problem(BaseModel):
    """RFC 9457 problem details, with the coordinator's refusal code and the job it named."""

    model_config = ConfigDict(extra="forbid")

    type: str = Field(description="urn:gridfleet:problem:<code>")
    title: str
    status: int = Field(ge=400, le=599)
    detail: str | None = Field(None, description="in words: the coordinator's reason verbatim")
    instance: str | None = Field(None, description="the request's path")
    code: str | None = Field(None, description="the machine-readable cause (STATUS_OF_CODE)")
    job_id: str | None = Field(None, description="the job a refusal concerns, if any")
    errors: list[FieldError] | None = Field(None, description="what in the request is wrong")


class ApiProblem(Exception):
    """Raised anywhere in a request: answered as the problem it describes."""

    def __init__(
        self,
        code: str,
        detail: str | None = None,
        *,
        job_id: str | None = None,
        errors: list[FieldError] | None = None,
        retry_after: int | None = None,
        headers: dict[str, str] | None = None,
    ) -> None:
        super().__init__(detail or code)
        self.code = code
        self.detail = detail
        self.job_id = job_id
        self.errors = errors
        self.retry_after = retry_after
        self.headers = dict(headers or {})

    @property
    def status(self) -> int:
        """Its HTTP status."""
        return status_of(self.code)

    def problem(self, instance: str | None = None) -> Problem:
        """Its body."""
        return Problem(
            type=TYPE_PREFIX + self.code,
            title=TITLES.get(self.status, "Error"),
            status=self.status,
            detail=self.detail,
            instance=instance,
            code=self.code,
            job_id=self.job_id,
            errors=self.errors,
        )

    def response(self, instance: str | None = None) -> Response:
        """Its response: the problem+json body, Retry-After and any headers of its own."""
        body = self.problem(instance).model_dump_json(exclude_none=True)
        response = Response(body, status=self.status, mimetype=PROBLEM_MEDIA)
        retry = self.retry_after
        if retry is None and self.status == 503:
            retry = RETRY_S
        if retry is not None:
            response.headers["Retry-After"] = str(max(1, retry))
        for name, value in self.headers.items():
            response.headers[name] = value
        response.headers["Cache-Control"] = "no-store"
        return response


def status_of(code: str) -> int:
    """The HTTP status of a refusal code (an unknown one: 422, as a refusal)."""
    return STATUS_OF_CODE.get(code, 422)


def refusal(code: str | None, reason: str | None, job_id: str | None = None) -> ApiProblem:
    """The coordinator's refusal as a problem: its code picks the status, its reason is kept."""
    return ApiProblem(code or UNCODED, reason or "refused by the coordinator", job_id=job_id)


def accepted(reply: Reply) -> Reply:
    """The coordinator's reply to a request, or its refusal as a problem (`refusal`)."""
    if not reply.accepted:
        raise refusal(reply.code, reply.reason, reply.job_id)
    return reply


def accepted_page(page: P | Reply) -> P:
    """The coordinator's page answering a query, or its refusal (a Reply in its place, or a
    page not accepted) as a problem (`refusal`)."""
    if isinstance(page, Reply):
        raise refusal(page.code, page.reason)
    if not page.accepted:
        raise refusal(None, page.reason)
    return page


def field_errors(exc: ValidationError) -> list[FieldError]:
    """A validation error's parts, without the input (it may be large, or a secret)."""
    return [
        FieldError(
            loc=[p if isinstance(p, int) else str(p) for p in e["loc"]],
            msg=e["msg"],
            type=e["type"],
        )
        for e in exc.errors(include_url=False, include_input=False, include_context=False)
    ][:50]


def invalid_request(exc: ValidationError) -> ApiProblem:
    """A request that is not as the document says: 400, saying each part that is wrong."""
    errors = field_errors(exc)
    first = errors[0] if errors else None
    where = ".".join(str(p) for p in first.loc) if first is not None else "request"
    detail = f"{where}: {first.msg}" if first is not None else "the request is not as documented"
    if len(errors) > 1:
        detail += f" (and {len(errors) - 1} more)"
    return ApiProblem("bad_request", detail, errors=errors)


def problem_responses(*statuses: int) -> ResponseDict:
    """The document's responses for these statuses: each a Problem, as problem+json."""
    return {
        str(status): {
            "description": TITLES.get(status, "Error"),
            "content": {PROBLEM_MEDIA: {"schema": {"$ref": "#/components/schemas/Problem"}}},
        }
        for status in statuses
    }
