"""The dashboard's HTTP API at /api/v1 (docs/api.md): a site's systems drive the fleet over HTTP.

flask-openapi3 routes it, checks each request against the pydantic models and writes the
OpenAPI 3.1 document from them; `DashboardApp` is its Flask subclass whose own route decorators
stay Flask's, so the page's routes are not part of the document. Every answer of /api/v1 that is
not a success is a problem (problems.py), a request from another site's page is refused, a body
must be a JSON object, and the caller is found before any route runs (identity.py).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from typing import Any

from flask import Flask, Response, g, request
from flask.json.provider import DefaultJSONProvider
from flask_openapi3.models.info import Info
from flask_openapi3.openapi import OpenAPI
from pydantic import ValidationError
from werkzeug.exceptions import HTTPException

from gridfleet.accounts import Account, Accounts
from gridfleet.dashboard.api import (
    routes_events,
    routes_jobs,
    routes_map,
    routes_records,
    routes_status,
    routes_stop,
    routes_units,
)
from gridfleet.dashboard.api.context import EXTENSION, PREFIX, ApiConfig, ApiContext, current
from gridfleet.dashboard.api.docs import INFO, install_docs
from gridfleet.dashboard.api.fleet import FleetClients
from gridfleet.dashboard.api.identity import Identity
from gridfleet.dashboard.api.problems import ApiProblem, Problem, invalid_request
from gridfleet.dashboard.api.web import http_problem, is_api
from gridfleet.dashboard.audit import LoginReporter
from gridfleet.protocol import Topics

log = logging.getLogger("gridfleet.dashboard.api")
MAX_BODY = 64 * 1024  # bytes of a request body (a job is ~100)
BODY_METHODS = ("POST", "PUT", "PATCH")
# What needs no caller: the document, its page and the page's files.
OPEN_PATHS = (f"{PREFIX}/openapi.json", f"{PREFIX}/docs", f"{PREFIX}/swagger/")
HTTP_CODES = {
    400: "bad_request",
    404: "not_found",
    405: "method_not_allowed",
    406: "not_acceptable",
    413: "payload_too_large",
}


def _problem_for_invalid(exc: ValidationError) -> Response:
    """flask-openapi3's answer to a request that its models refuse: a 400 problem."""
    return invalid_request(exc).response(request.path)


def whole_as_int(text: str) -> int | float:
    """A JSON number's text as an int when it is a whole number (`3.0`, `1e2`), as the protocol
    reads them (JSON, and JSON Schema, have one kind of number: 3.0 is the integer 3)."""
    number = float(text)
    return int(number) if number.is_integer() else number


class WholeNumbersJSON(DefaultJSONProvider):
    """Flask's JSON, reading whole numbers as integers; too deep a nesting is no JSON (a
    ValueError, as for any text that is none), not a crash."""

    def loads(self, s: str | bytes, **kwargs: Any) -> Any:
        try:
            return json.loads(s, parse_float=whole_as_int, **kwargs)
        except RecursionError:
            raise ValueError("JSON nested too deep") from None


class DashboardApp(OpenAPI):
    """The dashboard's Flask app, flask-openapi3's: the API's blueprints are documented and
    checked, the page's own routes (`app.get`, `app.post`) stay plain Flask routes."""

    json_provider_class = WholeNumbersJSON

    get = Flask.get
    post = Flask.post
    put = Flask.put
    patch = Flask.patch
    delete = Flask.delete

    def __init__(self, import_name: str, **kwargs: Any) -> None:
        super().__init__(
            import_name,
            info=Info(
                title=INFO["title"], version=INFO["version"], description=INFO["description"]
            ),
            security_schemes={
                "bearer": {
                    "type": "http",
                    "scheme": "bearer",
                    "bearerFormat": "gft1_<id>_<secret> ('gridfleet accounts token')",
                }
            },
            doc_ui=False,
            validation_error_status=400,
            validation_error_model=Problem,
            validation_error_callback=_problem_for_invalid,
            **kwargs,
        )


def install_api(
    app: DashboardApp,
    *,
    url: str,
    root: str,
    accounts: Callable[[], Accounts] | None,
    session_user: Callable[[], Account | None],
    reporter: LoginReporter | None = None,
    session_passwords: bool = False,
    config: ApiConfig | None = None,
) -> ApiContext:
    """Serve the API on `app`, reaching the fleet at broker `url` under topic `root`."""
    config = config or ApiConfig()
    clients = FleetClients(url, Topics(root), session_passwords, config.retry_s)
    context = ApiContext(config, Identity(accounts, session_user, reporter), clients)
    app.extensions[EXTENSION] = context
    for module in (
        routes_jobs,
        routes_units,
        routes_map,
        routes_stop,
        routes_records,
        routes_status,
        routes_events,
    ):
        app.register_api(module.api)
    install_docs(app, lambda: app.api_doc)
    app.before_request(_guard)
    app.register_error_handler(ApiProblem, _answer_problem)
    app.register_error_handler(HTTPException, http_problem)
    return context


def _guard() -> None:
    """Before an API route: the body's bounds, no other site's page, the caller, a JSON body
    (a bug here too is a problem, never the page's 500)."""
    try:
        _checked()
    except (ApiProblem, HTTPException):
        raise
    except Exception as exc:
        log.exception("api: checking %s %s failed", request.method, request.path)
        raise ApiProblem(
            "internal",
            f"internal error in the dashboard's API: {type(exc).__name__} (its log has the rest)",
        ) from None


def _checked() -> None:
    path = request.path
    if not is_api(path):
        return
    request.max_content_length = MAX_BODY
    if path.startswith(OPEN_PATHS) or request.routing_exception is not None:
        return  # open to all; or no such route (404) or method (405), said as a problem
    origin = request.headers.get("Origin")
    unsafe = request.method not in ("GET", "HEAD", "OPTIONS")
    if unsafe and origin is not None and origin.rstrip("/") != request.host_url.rstrip("/"):
        raise ApiProblem("cross_site", f"a request from {origin[:100]} is not this site's")
    g.api_caller = current().identity.caller(
        request.headers.get("Authorization"), request.remote_addr or "?", request.method
    )
    if request.method in BODY_METHODS:
        if not request.is_json:
            raise ApiProblem(
                "not_json", "send the body as JSON, with 'Content-Type: application/json'"
            )
        if not isinstance(request.get_json(silent=True), dict):
            raise ApiProblem("not_json", "the body is not a JSON object")


def _answer_problem(exc: ApiProblem) -> Response:
    return exc.response(request.path)
