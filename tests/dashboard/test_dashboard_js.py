"""The page's JavaScript: its pure modules (protocol helpers, fleet model, request bookkeeping, forms'
checks, click modes, connection, stop, view texts) run with Node's test runner, and its module graph."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest

from support.paths import REPO

DASHBOARD = REPO / "dashboard"
SCRIPTS = DASHBOARD / "static" / "js"
RELATIVE_IMPORT = re.compile(
    r"""^\s*(?:import|export)\b[^;]*?\bfrom\s+["'](\./[^"']+)["']""", re.M | re.S
)


@pytest.mark.skipif(shutil.which("node") is None, reason="Node.js is not installed")
def test_javascript_core() -> None:
    result = subprocess.run(
        ["node", "--test", "jstests/"],
        cwd=DASHBOARD,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "# fail 0" in result.stdout


def test_page_modules_all_load_from_main() -> None:
    """Every module main.js imports (directly or not) exists, and every module in static/js is used."""
    seen: set[str] = set()
    missing: list[str] = []
    todo = ["main.js"]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        path = SCRIPTS / name
        if not path.is_file():
            missing.append(name)
            continue
        for target in RELATIVE_IMPORT.findall(path.read_text(encoding="utf-8")):
            todo.append(target.removeprefix("./"))
    assert missing == [], f"imported but not in {SCRIPTS}: {missing}"
    unused = sorted(p.name for p in SCRIPTS.glob("*.js") if p.name not in seen)
    assert unused == [], f"in {SCRIPTS} but not loaded by the page: {unused}"
