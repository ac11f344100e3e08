"""The scenarios and maps gridfleet ships, found by name: `playfield` is the shipped playfield.

They are the checkout's `maps/`; a wheel carries them as `gridfleet/scenarios/` (pyproject's
package-dir), so an installed gridfleet runs them from wherever it is started.
"""

from __future__ import annotations

from pathlib import Path

from gridfleet.errors import GridfleetError

_HERE = Path(__file__).resolve().parent
INSTALLED = _HERE / "scenarios"  # in an installed wheel
CHECKOUT = _HERE.parent / "maps"  # in the checkout (an editable install runs from it)


def shipped_dir() -> Path:
    """The folder of the shipped scenarios and maps."""
    return INSTALLED if INSTALLED.is_dir() else CHECKOUT


def shipped_names(suffix: str) -> list[str]:
    """The names of the shipped files ending in `suffix` (".toml": scenarios, ".map": maps)."""
    return sorted(p.stem for p in shipped_dir().glob(f"*{suffix}"))


def shipped_file(name: str, suffix: str) -> Path:
    """The shipped file `name` + `suffix` (which may not exist)."""
    return shipped_dir() / f"{name}{suffix}"


def is_name(given: str | Path) -> bool:
    """Whether `given` is a bare name (`playfield`), not a path (`playfield.toml`, `maps/x`)."""
    text = str(given)
    return bool(text) and "/" not in text and "\\" not in text and Path(text).suffix == ""


def resolve(given: str | Path, suffix: str, what: str, error: type[GridfleetError]) -> Path:
    """The file `given` names: a path that exists wins; else a bare name is a shipped file
    (an unknown one raises `error` naming the shipped ones); any other path is left as it is."""
    path = Path(given)
    if path.exists() or not is_name(given):
        return path
    found = shipped_file(str(given), suffix)
    if found.is_file():
        return found
    names = ", ".join(shipped_names(suffix)) or "none"
    raise error(f"{given}: no such {what} file, and no shipped {what} of that name ({names})")
