"""The routes' common HTTP parts: their blueprints, the problems every route may answer, and a
JSON answer made from a model."""

from __future__ import annotations

import logging

from flask import Response, request
from flask_openapi3.blueprint import APIBlueprint
from flask_openapi3.models.tag import Tag
from flask_openapi3.types import ResponseDict
from pydantic import BaseModel
from werkzeug.exceptions import HTTPException
from werkzeug.sansio.response import Response as WerkzeugResponse

from gridfleet.dashboard.api.context import PREFIX
from gridfleet.dashboard.api.problems import ApiProblem, problem_responses

log = logging.getLogger("gridfleet.dashboard.api")
HTTP_CODES = {
    400: "bad_request",
    404: "not_found",
    405: "method_not_allowed",
    406: "not_acceptable",
    413: "payload_too_large",
}

SECURITY: list[dict[str, list[str]]] = [{"bearer": []}]
# What any route may answer besides its own: a request not as documented, no or a wrong token,
# a role that may not, too many wrong tokens (or streams), no coordinator or broker in time.
COMMON: ResponseDict = problem_responses(400, 401, 403, 429, 503)


def blueprint(name: str, description: str) -> APIBlueprint:
    """An API blueprint under /api/v1, tagged `name`, bearer tokens its security; a bug in
    one of its routes is a 500 problem in one line (the traceback to the log)."""
    api = APIBlueprint(
        f"api_{name}",
        __name__,
        url_prefix=PREFIX,
        abp_tags=[Tag(name=name, description=description)],
        abp_security=SECURITY,
        abp_responses=COMMON,
    )
    api.register_error_handler(Exception, internal_error)
    return api


def is_api(path: str) -> bool:
    """Whether `path` is the API's."""
    return path == PREFIX or path.startswith(PREFIX + "/")


def answer(model: BaseModel, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    """`model` as the JSON body of a response (never cached: it is the fleet now)."""
    response = Response(model.model_dump_json(), status=status, mimetype="application/json")
    response.headers["Cache-Control"] = "no-store"
    for name, value in (headers or {}).items():
        response.headers[name] = value
    return response


def also(*statuses: int) -> ResponseDict:
    """A route's own problem statuses, beside COMMON."""
    return problem_responses(*statuses)


def http_problem(exc: HTTPException) -> WerkzeugResponse | HTTPException:
    """An HTTP error of the API's paths as a problem; the page's as Flask answers them."""
    if not is_api(request.path):
        return exc
    if exc.response is not None:
        return exc.response  # flask-openapi3's 400, already a problem
    code = exc.code or 400
    problem = ApiProblem(HTTP_CODES.get(code, "bad_request"), exc.description)
    if code == 405:
        allowed = dict(exc.get_headers()).get("Allow")
        if allowed:
            problem.headers["Allow"] = allowed
    if code not in HTTP_CODES:
        problem = ApiProblem("bad_request", f"{exc.name}: {exc.description}")
    return problem.response(request.path)


def internal_error(exc: Exception) -> WerkzeugResponse:
    """A bug in a route: one line to the caller, the traceback to the log."""
    if isinstance(exc, ApiProblem):
        return exc.response(request.path)
    if isinstance(exc, HTTPException):
        answered = http_problem(exc)
        return (
            answered if isinstance(answered, WerkzeugResponse) else Response(status=exc.code or 500)
        )
    log.exception("api: %s %s failed", request.method, request.path)
    return ApiProblem(
        "internal",
        f"internal error in the dashboard's API: {type(exc).__name__} (its log has the rest)",
    ).response(request.path)
