"""The build's one step beyond pyproject.toml: the page's MQTT.js, from its npm package, into the
wheel (never committed: `npm ci` in dashboard/ fetches it as package-lock.json pins it)."""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.errors import FileError

HERE = Path(__file__).resolve().parent
BUNDLE = Path("dashboard") / "node_modules" / "mqtt" / "dist" / "mqtt.esm.js"
# Where dashboard/settings.py looks for it when there is no node_modules beside the package.
BUILT = Path("gridfleet") / "dashboard" / "vendor" / "mqtt.esm.js"


class BuildPy(build_py):
    """build_py, then MQTT.js's browser bundle copied into the built package."""

    def run(self) -> None:
        """Build the package, and copy the bundle in (an editable install serves node_modules')."""
        super().run()
        if self.editable_mode:
            return
        source = HERE / BUNDLE
        if not source.is_file():
            raise FileError(f"{BUNDLE} is missing: run npm ci in dashboard/ first")
        target = Path(self.build_lib) / BUILT
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)


setup(cmdclass={"build_py": BuildPy})
