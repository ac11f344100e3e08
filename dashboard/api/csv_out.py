"""The records as CSV: the same columns and cells as `gridfleet job history --csv` (and its
`--charges`) and `gridfleet audit --csv`, by their own code (pure)."""

from __future__ import annotations

import csv
import io

from flask import Response

from gridfleet.console.audit import print_csv
from gridfleet.console.job import CHARGES, JOB_CHANGES, HistoryShape
from gridfleet.protocol.messages import AuditEntry, ChargeEntry, JobHistoryEntry

CSV_MEDIA = "text/csv"


def history_csv(entries: list[JobHistoryEntry]) -> str:
    """Job changes as `gridfleet job history --csv` prints them."""
    return _shaped(JOB_CHANGES, entries)


def charges_csv(entries: list[ChargeEntry]) -> str:
    """Charge entries as `gridfleet job history --charges --csv` prints them."""
    return _shaped(CHARGES, entries)


def audit_csv(entries: list[AuditEntry]) -> str:
    """Audit entries as `gridfleet audit --csv` prints them."""
    out = io.StringIO()
    print_csv(entries, out)
    return out.getvalue()


def _shaped(shape: HistoryShape, entries: list[JobHistoryEntry] | list[ChargeEntry]) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(shape.columns)
    for entry in entries:
        writer.writerow(shape.row(entry))
    return out.getvalue()


def csv_answer(text: str, name: str, headers: dict[str, str] | None = None) -> Response:
    """CSV text as a download named `name`."""
    response = Response(text, mimetype=CSV_MEDIA)
    response.headers["Content-Disposition"] = f'attachment; filename="{name}"'
    response.headers["Cache-Control"] = "no-store"
    for key, value in (headers or {}).items():
        response.headers[key] = value
    return response
