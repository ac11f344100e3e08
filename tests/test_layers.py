"""The import layers: base ← components ← composition; tests and test helpers stay out of the product."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

BASE = "gridfleet"
COMPONENTS = ("broker", "coordinator", "robots", "dashboard", "device")
COMPOSITION = ("system", "bench")
PRODUCT = (BASE, *COMPONENTS, *COMPOSITION)
TESTS = Path(__file__).resolve().parent
# Test tools, and every module of tests/ (support and its helpers, conftest, the test modules).
TEST_ONLY = ("pytest", "tests", "playwright", "hypothesis", *(p.stem for p in TESTS.glob("*.py")))
TEST_ONLY += tuple(p.name for p in TESTS.iterdir() if (p / "__init__.py").exists())
# Optional extras a layer may use: `gridfleet bench page` drives Chromium (pyproject's `bench`).
EXTRAS = {"bench": {"playwright"}}


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
        elif isinstance(node, ast.Call) and _dynamic_import(node.func) and node.args:
            # importlib.import_module("x.y") / __import__("x"): an import all the same.
            name = node.args[0]
            if isinstance(name, ast.Constant) and isinstance(name.value, str):
                found.append((node.lineno, name.value.split(".")[0]))
    return found


def _dynamic_import(func: ast.expr) -> bool:
    """Whether a call is to `importlib.import_module`, `import_module` or `__import__`."""
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    return name in ("import_module", "__import__")


def crossings(root: Path = REPO) -> list[str]:
    """Every import that runs against the layers, as `file:line: a -> b`."""
    bad = []
    for package in PRODUCT:
        for path in sorted((root / package).rglob("*.py")):
            if "node_modules" in path.parts:
                continue
            for line, target in imports_of(path):
                first_party = target in PRODUCT and target not in allowed(package)
                if first_party or (target in TEST_ONLY and target not in EXTRAS.get(package, ())):
                    bad.append(f"{path.relative_to(root)}:{line}: {package} -> {target}")
    return bad


def test_no_import_crosses_the_layers() -> None:
    assert crossings() == []


def test_every_shipped_package_has_a_layer() -> None:
    # A package the layers do not name would never be checked.
    config = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    shipped = config["tool"]["setuptools"]["packages"]["find"]["include"]
    assert sorted(p.rstrip("*") for p in shipped) == sorted(PRODUCT)


@pytest.mark.parametrize(
    ("package", "source", "expected"),
    [
        ("gridfleet", "from coordinator.core import CoordinatorCore\n", "gridfleet -> coordinator"),
        ("robots", "def f():\n    import coordinator.service\n", "robots -> coordinator"),
        ("coordinator", "from system.cli import main\n", "coordinator -> system"),
        ("dashboard", "import pytest\n", "dashboard -> pytest"),
        ("bench", "from support.probe import MqttProbe\n", "bench -> support"),
        (
            "robots",
            "import importlib\nimportlib.import_module('coordinator.core')\n",
            "robots -> coordinator",
        ),
        ("device", "__import__('dashboard')\n", "device -> dashboard"),
        (
            "coordinator",
            "from test_peers import Wire\n",
            "coordinator -> test_peers",
        ),
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
