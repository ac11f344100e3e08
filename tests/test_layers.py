"""The import layers: base ← components ← composition; tests and test helpers stay out of the product."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

BASE = "gridfleet"
COMPONENTS = ("broker", "coordinator", "robots", "dashboard", "device")
COMPOSITION = ("system", "bench")
PRODUCT = (BASE, *COMPONENTS, *COMPOSITION)
TEST_ONLY = ("pytest", "support", "tests", "playwright", "hypothesis")


def allowed(importer: str) -> set[str]:
    """The first-party packages a module of package `importer` may import."""
    if importer == BASE:
        return {BASE}
    if importer in COMPONENTS:
        return {BASE, importer}
    return set(PRODUCT)


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, top-level package) of every import in `path`, including those inside functions."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name.split(".")[0]) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module.split(".")[0]))
    return found


def crossings(root: Path = REPO) -> list[str]:
    """Every import that runs against the layers, as `file:line: a -> b`."""
    bad = []
    for package in PRODUCT:
        for path in sorted((root / package).rglob("*.py")):
            if "node_modules" in path.parts:
                continue
            for line, target in imports_of(path):
                first_party = target in PRODUCT and target not in allowed(package)
                if first_party or target in TEST_ONLY:
                    bad.append(f"{path.relative_to(root)}:{line}: {package} -> {target}")
    return bad


def test_no_import_crosses_the_layers() -> None:
    assert crossings() == []


@pytest.mark.parametrize(
    ("package", "source", "expected"),
    [
        ("gridfleet", "from coordinator.core import CoordinatorCore\n", "gridfleet -> coordinator"),
        ("robots", "def f():\n    import coordinator.service\n", "robots -> coordinator"),
        ("coordinator", "from system.cli import main\n", "coordinator -> system"),
        ("dashboard", "import pytest\n", "dashboard -> pytest"),
        ("bench", "from support.probe import MqttProbe\n", "bench -> support"),
    ],
)
def test_the_check_catches_each_kind_of_crossing(
    tmp_path: Path, package: str, source: str, expected: str
) -> None:
    (tmp_path / package).mkdir()
    (tmp_path / package / "bad.py").write_text(source, encoding="utf-8")
    assert [c.split(": ", 1)[1] for c in crossings(tmp_path)] == [expected]


def test_a_component_may_import_the_base_and_itself(tmp_path: Path) -> None:
    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "ok.py").write_text(
        "from gridfleet.grid import Cell\nfrom robots.world import WorldSim\nimport numpy\n",
        encoding="utf-8",
    )
    assert crossings(tmp_path) == []
