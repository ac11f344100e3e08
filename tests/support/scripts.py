"""The checkout's scripts (`script/`, no part of the package), loaded as modules for the tests."""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType

from support.paths import REPO


def load_script(name: str) -> ModuleType:
    """`script/<name>.py` as the module `script_<name>` (loaded once)."""
    module_name = f"script_{name}"
    if module_name in sys.modules:
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, REPO / "script" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    spec.loader.exec_module(module)
    return module


gen_protocol = load_script("gen_protocol")
