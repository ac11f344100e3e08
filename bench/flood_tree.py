"""`gridfleet bench flood`'s processes: the code they run (this checkout, or a wheel of another
tree) and the broker, coordinator and units started from it, each a process of its own."""

from __future__ import annotations

import contextlib
import os
import queue
import re
import shutil
import subprocess
import sys
import threading
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from gridfleet.errors import ConfigError
from gridfleet.lifeline import PARENT_ENV

READY_S = 60.0  # a component that has not said it is ready within this failed to start
STOP_S = 20.0  # a component that has not ended this long after SIGTERM is killed
BROKER_READY = re.compile(r"listening on (mqtt://\S+)")
DROPPING = re.compile(r"client (\S+) is not reading: dropping .*?first on (\S+)")


@dataclass(frozen=True)
class Tree:
    """The code the components run: its label, its PYTHONPATH (None: this checkout's install)
    and where a subprocess imports `gridfleet.coordinator` from (checked once)."""

    label: str
    pythonpath: Path | None
    imports: str

    def env(self) -> dict[str, str]:
        """The environment of a component run from this tree."""
        env = dict(os.environ)
        env.pop("PYTHONPATH", None)
        if self.pythonpath is not None:
            env["PYTHONPATH"] = str(self.pythonpath)
        return env


def _imports(env: dict[str, str], cwd: Path) -> str:
    """Where a subprocess with `env` imports `gridfleet.coordinator` from."""
    code = "import gridfleet.coordinator as c; print(c.__file__)"
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True, text=True, timeout=60
    )
    if done.returncode != 0:
        raise ConfigError(f"cannot import gridfleet: {done.stderr.strip().splitlines()[-1:]}")
    return done.stdout.strip()


def this_checkout(work: Path) -> Tree:
    """This checkout, as the venv has it installed."""
    tree = Tree("this checkout", None, "")
    return Tree(tree.label, None, _imports(tree.env(), work))


def _copy_sources(tree: Path, into: Path) -> None:
    """The tree's files as git sees them (committed, changed and new; not ignored) into `into`:
    a build in the tree itself would leave build/ there, whose stale files a later build takes."""
    listed = subprocess.run(
        ["git", "-C", str(tree), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        capture_output=True,
        timeout=60,
    )
    if listed.returncode != 0:
        raise ConfigError(f"--tree {tree}: not a git checkout ({listed.stderr.decode().strip()})")
    for name in listed.stdout.decode().split("\0"):
        source = tree / name
        if name and source.is_file():
            target = into / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)


# The page's MQTT.js, which a wheel's build takes from npm's folder (setup.py): git ignores it.
PAGE_BUNDLE = Path("dashboard") / "node_modules" / "mqtt" / "dist" / "mqtt.esm.js"


def _copy_page_bundle(tree: Path, into: Path) -> None:
    """The tree's MQTT.js bundle into `into`, or this checkout's when the tree has none (a git
    worktree has no node_modules); nothing where neither has one (an older tree needs none)."""
    here = Path(__file__).resolve().parents[1]
    for bundle in (tree / PAGE_BUNDLE, here / PAGE_BUNDLE):
        if bundle.is_file():
            (into / PAGE_BUNDLE).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(bundle, into / PAGE_BUNDLE)
            return


def wheel_tree(directory: str, work: Path) -> Tree:
    """A wheel of the checkout at `directory`, unzipped under `work`, checked to be what a
    subprocess with its PYTHONPATH imports."""
    tree = Path(directory).resolve()
    if not (tree / "pyproject.toml").is_file():
        raise ConfigError(f"--tree {directory}: no pyproject.toml there")
    n = len(list(work.glob("tree-*")))
    base = work / f"tree-{n}"
    source, wheels, site = base / "src", base / "wheels", base / "site"
    source.mkdir(parents=True)
    _copy_sources(tree, source)
    _copy_page_bundle(tree, source)
    pip = [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", str(source), "-w", str(wheels)]
    # Without isolation first, as asked; a venv whose setuptools is too old for the tree's
    # pyproject (license = "MIT" needs setuptools 77) builds it in an isolated environment.
    built = subprocess.run([*pip, "--no-build-isolation"], capture_output=True, text=True)
    if built.returncode != 0:
        built = subprocess.run(pip, capture_output=True, text=True)
    found = sorted(wheels.glob("gridfleet-*.whl"))
    if built.returncode != 0 or not found:
        said = (built.stderr.strip().splitlines() or ["no wheel"])[-1]
        raise ConfigError(f"--tree {directory}: the wheel did not build: {said}")
    with zipfile.ZipFile(found[0]) as wheel:
        wheel.extractall(site)
    label = str(tree)
    imports = _imports(Tree(label, site, "").env(), work)
    if not imports.startswith(str(site)):
        raise ConfigError(f"--tree {directory}: a subprocess imported {imports}, not {site}")
    return Tree(label, site, imports)


class Component:
    """One component (`gridfleet <command> …`) as a process, its output in a log file."""

    def __init__(self, name: str, argv: list[str], tree: Tree, work: Path) -> None:
        self.name = name
        self.log = work / f"{name}.log"
        self._out: IO[str] = self.log.open("w+", encoding="utf-8")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "gridfleet", *argv],
            stdout=subprocess.PIPE if name == "broker" else self._out,
            stderr=self._out,
            text=True,
            # It ends with this process however that ends (a flood's test timed out and left its
            # broker, coordinator and units running); a tree without the lifeline ignores it.
            env={**tree.env(), PARENT_ENV: str(os.getpid())},
            cwd=work,  # not a checkout: its gridfleet/ folder would shadow the tree's
        )

    def first_line(self, timeout: float = READY_S) -> str:
        """The first line on its stdout (its readiness), or ConfigError after `timeout`; the
        rest is read on and kept too, so that a full pipe never blocks it."""
        assert self.proc.stdout is not None
        lines: queue.Queue[str] = queue.Queue()
        stdout = self.proc.stdout

        def read() -> None:
            with contextlib.suppress(ValueError, OSError):  # closed when it is stopped
                for line in stdout:
                    lines.put(line)
            lines.put("")

        threading.Thread(target=read, daemon=True).start()
        try:
            return lines.get(timeout=timeout)
        except queue.Empty:
            raise ConfigError(f"{self.name} said nothing within {timeout:.0f} s") from None

    def check(self) -> None:
        """ConfigError with its last words if it has died."""
        if self.proc.poll() is not None:
            raise ConfigError(
                f"{self.name} died (exit {self.proc.returncode}): {self.last_words()}"
            )

    def last_words(self) -> str:
        """The last line of its log."""
        text = self.log.read_text(encoding="utf-8", errors="replace").strip().splitlines()
        return text[-1] if text else "nothing logged"

    def stop(self) -> None:
        """SIGTERM, then SIGKILL after STOP_S; closes its log."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(STOP_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(STOP_S)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self._out.close()


@dataclass(frozen=True)
class Layout:
    """What the components are given: files, root, step and the coordinator's metrics port."""

    accounts: Path
    scenario: Path
    map: Path
    db: Path
    truth: Path
    root: str
    step_s: float
    metrics_port: int


class Components:
    """The broker, the coordinator and the units, started in that order, stopped in reverse."""

    def __init__(self, tree: Tree, layout: Layout, work: Path) -> None:
        self.tree, self.layout, self.work = tree, layout, work
        self.running: list[Component] = []
        self.url = ""

    def start(self) -> str:
        """Start all three; the broker's URL."""
        lay = self.layout
        logins = ["--accounts", str(lay.accounts)]
        broker = self._start("broker", ["broker", "--port", "0", "--no-ws", "--root", lay.root])
        line = broker.first_line()
        found = BROKER_READY.search(line)
        if found is None:
            broker.check()
            raise ConfigError(f"the broker did not start: {line.strip() or broker.last_words()}")
        self.url = found.group(1)
        common = ["--broker", self.url, "--root", lay.root, *logins, "--step", str(lay.step_s)]
        coordinator = ["coordinator", *common, "--map", str(lay.map), "--db", str(lay.db)]
        self._start(
            "coordinator", [*coordinator, "--vouched-senders", "--metrics", str(lay.metrics_port)]
        )
        self._start(
            "robots",
            ["robots", *common, "--scenario", str(lay.scenario), "--truth", str(lay.truth)],
        )
        return self.url

    def _start(self, name: str, argv: list[str]) -> Component:
        if name == "broker":
            argv = [*argv, "--accounts", str(self.layout.accounts)]
        component = Component(name, argv, self.tree, self.work)
        self.running.append(component)
        return component

    def check(self) -> None:
        """ConfigError naming a component that died."""
        for component in self.running:
            component.check()

    def stop(self) -> None:
        """Stop every component, the units first, the broker last."""
        for component in reversed(self.running):
            component.stop()
        self.running = []

    def dropping(self) -> list[str]:
        """The broker's "not reading: dropping" lines, as `client (first on topic)`."""
        log = self.work / "broker.log"
        if not log.exists():
            return []
        text = log.read_text(encoding="utf-8", errors="replace")
        return [f"{m.group(1)} (first on {m.group(2)})" for m in DROPPING.finditer(text)]


def wait_until(
    done: Callable[[], bool], timeout: float, what: str, check: Callable[[], None] | None = None
) -> None:
    """Poll `done()` every 50 ms until true; ConfigError naming `what` after `timeout` s."""
    deadline = time.monotonic() + timeout
    while not done():
        if check is not None:
            check()
        if time.monotonic() > deadline:
            raise ConfigError(f"{what} within {timeout:.0f} s")
        time.sleep(0.05)  # polling, with a deadline
