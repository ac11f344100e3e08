"""The OpenAPI 3.1 document at /api/v1/openapi.json and the page that renders it, /api/v1/docs.

flask-openapi3 makes the document from the routes and their pydantic models. Its own schema
objects keep only the keywords they know (they drop `propertyNames` and `patternProperties`,
which say what a map's keys may be), so the components are put back as pydantic itself writes
them: the document then says what the models check, keyword for keyword. The page is Swagger UI from
flask-openapi3-swagger's own files (no CDN), under a CSP of its own that lets in its one inline
script by its hash.
"""

from __future__ import annotations

import base64
import copy
import hashlib
import re
from pathlib import Path
from typing import Any, Literal

import flask_openapi3_swagger
from flask import Blueprint, Flask, Response, jsonify, render_template_string
from flask_openapi3.utils import normalize_name
from flask_openapi3_swagger.templates import swagger_html_string
from pydantic import BaseModel

from gridfleet.dashboard.api.context import PREFIX
from gridfleet.dashboard.api.models import (
    Accepted,
    AuditList,
    ChargesPage,
    ControlRequest,
    HistoryPage,
    JobRequest,
    JobsPage,
    PlacesList,
    StopRequest,
    StopState,
    UnitsList,
    UnitView,
    ZoneEvent,
    ZoneRequest,
    ZonesList,
)
from gridfleet.dashboard.api.problems import Problem
from gridfleet.protocol import CoordinatorStatus
from gridfleet.protocol.messages import JobView, Zone

REF = "#/components/schemas/{model}"
SWAGGER_FILES = Path(flask_openapi3_swagger.__file__).parent / "templates" / "swagger"
# Every model the document names, as a request body reads it or as an answer writes it.
DOCUMENTED: tuple[tuple[type[BaseModel], Literal["validation", "serialization"]], ...] = (
    (JobRequest, "validation"),
    (ZoneRequest, "validation"),
    (ControlRequest, "validation"),
    (StopRequest, "validation"),
    (JobView, "serialization"),
    (JobsPage, "serialization"),
    (UnitView, "serialization"),
    (UnitsList, "serialization"),
    (PlacesList, "serialization"),
    (Zone, "serialization"),
    (ZonesList, "serialization"),
    (Accepted, "serialization"),
    (StopState, "serialization"),
    (HistoryPage, "serialization"),
    (ChargesPage, "serialization"),
    (AuditList, "serialization"),
    (ZoneEvent, "serialization"),
    (CoordinatorStatus, "serialization"),
    (Problem, "serialization"),
)
INFO = {
    "title": "gridfleet HTTP API",
    "version": "1",
    "description": "A site's systems drive the fleet over HTTP: jobs (by place names or squares, "
    "idempotent with an Idempotency-Key), units, places, closed zones, the emergency stop, the "
    "job history and the audit, and the fleet's changes as server-sent events. With accounts, "
    "send `Authorization: Bearer TOKEN` (`gridfleet accounts token NAME --file FILE`). Errors "
    "are RFC 9457 problem details. docs/api.md has a worked example.",
}


def components(
    models: tuple[tuple[type[BaseModel], Literal["validation", "serialization"]], ...],
) -> dict[str, Any]:
    """Each model's JSON Schema as pydantic writes it, and those of the models inside them."""
    schemas: dict[str, Any] = {}
    for model, mode in models:
        schema = model.model_json_schema(ref_template=REF, mode=mode)
        schemas.update(schema.pop("$defs", {}))
        schemas[normalize_name(schema.get("title") or model.__name__)] = schema
    return schemas


def same_items(schema: Any) -> Any:
    """`schema` with each tuple of one kind (a square: [x, y], both 0-4095) said as an array of
    exactly that many such items: the same rule, in the words every tool reads (Swagger UI and
    schemathesis stumble over `prefixItems`)."""
    if isinstance(schema, list):
        return [same_items(s) for s in schema]
    if not isinstance(schema, dict):
        return schema
    out = {k: same_items(v) for k, v in schema.items()}
    prefix = out.get("prefixItems")
    if (
        isinstance(prefix, list)
        and prefix
        and all(p == prefix[0] for p in prefix)
        and out.get("minItems") == out.get("maxItems") == len(prefix)
        and "items" not in out
    ):
        del out["prefixItems"]
        out["items"] = prefix[0]
    return out


def full_document(generated: dict[str, Any]) -> dict[str, Any]:
    """flask-openapi3's document with the components as pydantic writes them."""
    document = copy.deepcopy(generated)
    found = document.setdefault("components", {}).setdefault("schemas", {})
    found.update(components(DOCUMENTED))
    result = same_items(document)
    assert isinstance(result, dict)
    return result


def inline_script_hash(page: str) -> str:
    """The CSP source of the page's one inline script ('sha256-…')."""
    scripts = re.findall(r"<script>(.*?)</script>", page, re.S)
    assert len(scripts) == 1, f"the docs page has {len(scripts)} inline scripts, not one"
    digest = hashlib.sha256(scripts[0].encode("utf-8")).digest()
    return f"'sha256-{base64.b64encode(digest).decode()}'"


def docs_policy(script_hash: str) -> str:
    """The docs page's CSP: its own files, its one inline script, Swagger UI's inline styles."""
    return (
        f"default-src 'self'; script-src 'self' {script_hash}; style-src 'self' 'unsafe-inline'; "
        "img-src 'self' data:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
        "form-action 'self'; frame-ancestors 'none'"
    )


def install_docs(app: Flask, generated: Any) -> None:
    """The document, the page and the page's files, under /api/v1."""
    files = Blueprint(
        "api_docs", __name__, static_folder=str(SWAGGER_FILES), static_url_path=f"{PREFIX}/swagger"
    )
    cache: dict[str, Any] = {}

    @files.get(f"{PREFIX}/openapi.json")
    def openapi_json() -> Response:
        if "document" not in cache:
            cache["document"] = full_document(generated())
        return jsonify(cache["document"])

    @files.get(f"{PREFIX}/docs")
    def docs_page() -> Response:
        if "page" not in cache:
            page = render_template_string(
                swagger_html_string,
                doc_url="openapi.json",
                # No validator badge: it would ask validator.swagger.io about the document.
                swagger_config={"validatorUrl": None, "persistAuthorization": False},
                oauth_config=None,
            )
            cache["page"] = (page, docs_policy(inline_script_hash(page)))
        page, policy = cache["page"]
        response = Response(page, mimetype="text/html")
        response.headers["Content-Security-Policy"] = policy
        return response

    app.register_blueprint(files)
