"""Reading the text files a user points at (maps, scenarios, configs, benchmark data)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any, Generic, TypeVar

from gridfleet.errors import GridfleetError


def read_text(path: Path, what: str, error: type[GridfleetError]) -> str:
    """The UTF-8 text of `path`; a missing or unreadable file raises `error` naming it."""
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: no such {what} file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read {what}: {exc}") from None


E = TypeVar("E", bound=GridfleetError)


class TomlFile(Generic[E]):
    """A TOML file read for a person: its data, and the line of a key or of the n-th `[[table]]`
    for errors in one line (`file:line: problem`)."""

    def __init__(self, path: Path, what: str, error: type[E]) -> None:
        self.path = path
        self._error = error
        text = read_text(path, what, error)
        self.lines = text.splitlines()
        self._tables: dict[str, list[int]] = {}  # each [[name]]'s lines, once asked for
        try:
            self.data: dict[str, Any] = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            match = re.search(r"line (\d+)", str(exc))
            end = str(max(1, len(self.lines)))
            line = match.group(1) if match else (end if "end of document" in str(exc) else "1")
            raise error(f"{path}:{line}: not valid TOML: {exc}") from None

    def key(self, key: str) -> int:
        """The line of `key = …` (the first; 1 when there is none)."""
        pattern = re.compile(rf"^\s*{re.escape(key)}\s*=")
        return next((i for i, line in enumerate(self.lines, 1) if pattern.match(line)), 1)

    def section(self, name: str) -> int:
        """The line of `[name]` (else of `name = …`)."""
        pattern = re.compile(rf"^\s*\[\s*{re.escape(name)}\s*\]")
        hit = next((i for i, line in enumerate(self.lines, 1) if pattern.match(line)), None)
        return hit if hit is not None else self.key(name)

    def table(self, name: str, index: int) -> int:
        """The line of the `index`-th `[[name]]` (else of `name = …`)."""
        hits = self._tables.get(name)
        if hits is None:  # found once per name: a file may have thousands of tables
            pattern = re.compile(rf"^\s*\[\[\s*{re.escape(name)}\s*\]\]")
            hits = self._tables[name] = [
                i for i, line in enumerate(self.lines, 1) if pattern.match(line)
            ]
        return hits[index] if index < len(hits) else self.key(name)

    def error(self, line: int, problem: str) -> E:
        """The error to raise for `problem` at `line`."""
        return self._error(f"{self.path}:{line}: {problem}")
