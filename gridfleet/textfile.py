"""Reading the text files a user points at (maps, scenarios, configs, benchmark data)."""

from __future__ import annotations

from pathlib import Path

from gridfleet.errors import GridfleetError


def read_text(path: Path, what: str, error: type[GridfleetError]) -> str:
    """The UTF-8 text of `path`; a missing or unreadable file raises `error` naming it."""
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: no such {what} file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read {what}: {exc}") from None
