"""The import layers: base ← components ← composition; tests and test helpers stay out of the product."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from support.paths import REPO

pytestmark = pytest.mark.slow  # seconds a test: in make test, not in test-fast

BASE = "gridfleet"
COMPONENTS = ("broker", "coordinator", "robots", "dashboard", "device", "console", "alerts")
COMPOSITION = ("system", "bench")  # bench stands on system: system never imports bench
PARTS = (*COMPONENTS, *COMPOSITION)  # folders at the top of the checkout, installed as gridfleet.*
PRODUCT = (BASE, *PARTS)
DATA = {f"{BASE}.scenarios": "maps"}  # installed with the code, as data: the shipped scenarios
# `python -m gridfleet` is the command line: the base's one file that starts the composition.
ENTRY = Path(BASE) / "__main__.py"
TESTS = REPO / "tests"
# Test tools, and every module of tests/ (support and its helpers, the conftest files, the test
# modules of each component's folder).
TEST_ONLY = ("pytest", "tests", "playwright", "hypothesis", *(p.stem for p in TESTS.glob("*.py")))
TEST_ONLY += tuple(p.stem for p in TESTS.glob("*/test_*.py"))
TEST_ONLY += tuple(p.name for p in TESTS.iterdir() if (p / "__init__.py").exists())
# Optional extras a layer may use: `gridfleet bench page` drives Chromium (pyproject's `bench`).
EXTRAS = {"bench": {"playwright"}}


def allowed(importer: str) -> set[str]:
    """The layers a module of layer `importer` may import."""
    if importer == BASE:
        return {BASE}
    if importer == "dashboard":
        # The HTTP API is a client of the fleet as the CLI is: it drives the console's operator
        # client and prints the console's CSV (dashboard/api/); nothing in console imports it.
        return {BASE, importer, "console"}
    if importer in COMPONENTS:
        return {BASE, importer}
    if importer == "system":
        return {BASE, *COMPONENTS, "system"}
    return set(PRODUCT)


def layer_of(module: str) -> str:
    """The layer an imported module belongs to (`gridfleet.robots.x` -> robots), or its package."""
    parts = module.split(".")
    if parts[0] == BASE and len(parts) > 1 and parts[1] in PARTS:
        return parts[1]
    return parts[0]


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import in `path`, including those inside functions."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
        elif isinstance(node, ast.Call) and _dynamic_import(node.func) and node.args:
            # importlib.import_module("x.y") / __import__("x"): an import all the same.
            name = node.args[0]
            if isinstance(name, ast.Constant) and isinstance(name.value, str):
                found.append((node.lineno, name.value))
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
            for line, module in imports_of(path):
                target = layer_of(module)
                where = f"{path.relative_to(root)}:{line}: {package} -> "
                if target in PARTS and module.split(".")[0] == target:
                    bad.append(where + f"{target} (not as gridfleet.{target})")
                elif target in PRODUCT and target not in allowed(package):
                    if not (path.relative_to(root) == ENTRY and target == "system"):
                        bad.append(where + target)
                elif target in TEST_ONLY and target not in EXTRAS.get(package, ()):
                    bad.append(where + target)
    return bad


def test_no_import_crosses_the_layers() -> None:
    assert crossings() == []


def test_every_shipped_package_has_a_layer() -> None:
    # A package the layers do not name would never be checked.
    config = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    shipped = config["tool"]["setuptools"]["package-dir"]
    assert shipped == {BASE: BASE} | {f"{BASE}.{part}": part for part in PARTS} | DATA
    # A data package holds no code to check.
    assert not [p for folder in DATA.values() for p in (REPO / folder).rglob("*.py")]


@pytest.mark.parametrize(
    ("package", "source", "expected"),
    [
        (
            "gridfleet",
            "from gridfleet.coordinator.core import CoordinatorCore\n",
            "gridfleet -> coordinator",
        ),
        ("robots", "def f():\n    import gridfleet.coordinator.shell\n", "robots -> coordinator"),
        ("coordinator", "from gridfleet.system.cli import main\n", "coordinator -> system"),
        ("system", "from gridfleet.bench.cli import run\n", "system -> bench"),
        (
            "robots",
            "from robots.world import WorldSim\n",
            "robots -> robots (not as gridfleet.robots)",
        ),
        ("dashboard", "import pytest\n", "dashboard -> pytest"),
        ("bench", "from support.probe import MqttProbe\n", "bench -> support"),
        (
            "robots",
            "import importlib\nimportlib.import_module('gridfleet.coordinator.core')\n",
            "robots -> coordinator",
        ),
        ("device", "__import__('gridfleet.dashboard')\n", "device -> dashboard"),
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
        "from gridfleet.grid import Cell\nfrom gridfleet.robots.world import WorldSim\nimport numpy\n",
        encoding="utf-8",
    )
    assert crossings(tmp_path) == []


# ---- the planning library ---------------------------------------------------------------------

PLANNING = f"{BASE}.coordinator.planning"  # a library: the coordinator and the bench use it


def planning_reaches(root: Path = REPO) -> list[str]:
    """Each import of the rest of the coordinator in the planning library (`file:line: module`)."""
    bad = []
    for path in sorted((root / "coordinator" / "planning").rglob("*.py")):
        for line, module in imports_of(path):
            inside = module == PLANNING or module.startswith(PLANNING + ".")
            if layer_of(module) == "coordinator" and not inside:
                bad.append(f"{path.relative_to(root)}:{line}: {module}")
    return bad


def test_the_planning_library_imports_nothing_else_of_the_coordinator() -> None:
    assert (REPO / "coordinator" / "planning" / "planner.py").exists()
    assert planning_reaches() == []


def test_the_planning_check_catches_an_import_of_the_coordinator(tmp_path: Path) -> None:
    (tmp_path / "coordinator" / "planning").mkdir(parents=True)
    (tmp_path / "coordinator" / "planning" / "bad.py").write_text(
        "from gridfleet.coordinator.planning.pibt import PIBT\n"
        "def f():\n    from gridfleet.coordinator.world import World\n",
        encoding="utf-8",
    )
    assert planning_reaches(tmp_path) == [
        "coordinator/planning/bad.py:3: gridfleet.coordinator.world"
    ]


# ---- the pure cores ----------------------------------------------------------------------------

# What a pure core must never load, directly or through anything it imports.
IO_MODULES = {"asyncio", "aiomqtt", "paho", "sqlite3", "socket"}
CORES = (
    "gridfleet.coordinator.core",
    "gridfleet.coordinator.stop",
    "gridfleet.coordinator.planning.planner",
    "gridfleet.coordinator.allocation",
    "gridfleet.coordinator.world",
    "gridfleet.robots.unit",
    "gridfleet.robots.core",
    "gridfleet.robots.fleet_side",
    "gridfleet.device.core",
    "gridfleet.robots.vda5050.orders",
    "gridfleet.robots.vda5050.states",
    "gridfleet.robots.vda5050.core",
    "gridfleet.robots.vda5050.pause_cancel",
    "gridfleet.robots.vda5050.resend",
    "gridfleet.robots.vda5050.refusals",
    "gridfleet.robots.vda5050.virtual",
    "gridfleet.alerts.core",
)


def io_chains(module: str, root: Path = REPO) -> list[str]:
    """Each I/O module that importing `module` loads, with the chain of imports that brought it.

    Python's own import log (-X importtime) nests each import under the one that caused it.
    """
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", f"import {module}"],
        capture_output=True,
        text=True,
        cwd=root,
        timeout=60,
        env={**os.environ, "PYTHONPATH": str(root)},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [line.split("|")[2] for line in done.stderr.splitlines() if line.count("|") == 2]
    entries = [(len(r) - len(r.lstrip()), r.strip()) for r in rows[1:]]  # (depth, name)
    found, reported = [], set()
    for i, (depth, name) in enumerate(entries):
        package = name.split(".")[0]
        if package not in IO_MODULES or package in reported:
            continue
        reported.add(package)
        # A module is logged once its own imports are done: its importer is the next one up.
        chain, want = [name], depth
        for up_depth, up_name in entries[i + 1 :]:
            if up_depth < want:
                chain.append(up_name)
                want = up_depth
        while len(chain) > 1 and chain[1].split(".")[0] == package:
            chain.pop(0)  # from the package itself, not its first submodule
        found.append(" <- ".join(chain))
    return found


@pytest.mark.parametrize("module", CORES)
def test_a_pure_core_loads_no_io(module: str) -> None:
    assert io_chains(module) == []


def test_the_purity_check_names_the_chain_that_brought_io_in(tmp_path: Path) -> None:
    (tmp_path / "fakecore").mkdir()
    (tmp_path / "fakecore" / "__init__.py").write_text("", encoding="utf-8")
    (tmp_path / "fakecore" / "helper.py").write_text("import sqlite3\n", encoding="utf-8")
    (tmp_path / "fakecore" / "core.py").write_text("import fakecore.helper\n", encoding="utf-8")
    assert io_chains("fakecore.core", tmp_path) == ["sqlite3 <- fakecore.helper <- fakecore.core"]


# Run by test_the_cores_drive_a_whole_scenario_without_touching_the_network: Python's audit hooks
# see every socket, database and process a program opens, however it was imported.
_NO_IO_RUN = """
import sys

def refuse(event, args):
    if event.split(".")[0] in {"socket", "sqlite3", "subprocess"} or event == "os.system":
        raise SystemExit(f"I/O from a pure core: {event} {args!r}")

from gridfleet.scenario import load_scenario
from gridfleet.system.lockstep import run_lockstep

scenario = load_scenario(sys.argv[1])
sys.addaudithook(refuse)
result = run_lockstep(scenario, 0.1, 2000, 0)
assert result.finished and result.collisions == 0, result
print("jobs done:", sum(j["state"] == "done" for j in result.jobs))
"""


def test_the_cores_drive_a_whole_scenario_without_touching_the_network() -> None:
    # The import check above sees modules; this sees deeds. scipy, loaded on first use, brings in
    # the socket module through importlib.metadata: no socket may ever be made with it.
    done = subprocess.run(
        [sys.executable, "-c", _NO_IO_RUN, str(REPO / "maps" / "warehouse.toml")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("jobs done: ") and int(done.stdout.split()[-1]) > 0


def test_the_audit_hook_run_catches_a_socket(tmp_path: Path) -> None:
    script = _NO_IO_RUN.replace(
        "result = run_lockstep", "import socket; socket.socket()\nresult = run_lockstep"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(REPO / "maps" / "corridor.toml")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 1 and "I/O from a pure core: socket.__new__" in done.stderr


# The commands a person types again and again start without numpy (a quarter of a second of
# every start): the protocol's squares are plain tuples (gridfleet/squares.py), not the map's.
QUICK_COMMANDS = (
    "gridfleet.system.cli",
    "gridfleet.console.job",
    "gridfleet.console.status",
    "gridfleet.console.audit",
    "gridfleet.console.clean",
    "gridfleet.alerts.cli",
    "gridfleet.device.cli",
)


def test_the_quick_commands_start_without_numpy() -> None:
    imports = "; ".join(f"import {m}" for m in QUICK_COMMANDS)
    done = subprocess.run(
        [sys.executable, "-c", f"{imports}; import sys; print('numpy' in sys.modules)"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=60,
    )
    assert (done.returncode, done.stdout.strip()) == (0, "False"), done.stderr[-2000:]
