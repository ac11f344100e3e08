"""`gridfleet bench`: run one of the benchmarks and report medians."""

from __future__ import annotations

import argparse
import importlib
from typing import Any

from gridfleet.errors import ConfigError
from gridfleet.options import GridfleetParser

# What pyproject's `bench` extra brings; a bench that needs one missing says how to install it.
BENCH_EXTRA = {"psutil", "playwright", "matplotlib", "httpx", "msgspec", "orjson"}

# name -> (module, help). Each module offers add_arguments(parser) and run(args) -> int.
BENCHES: dict[str, tuple[str, str]] = {
    "planner": (
        "gridfleet.bench.planner_cli",
        "the planner alone on public MAPF instances (no broker)",
    ),
    "system": (
        "gridfleet.bench.system.cli",
        "the whole system over a real broker: throughput, stop latency",
    ),
    "page": (
        "gridfleet.bench.page_cli",
        "the dashboard in Chromium at fleet scale: frame budget, fleet cost",
    ),
    "soak": (
        "gridfleet.bench.soak.cli",
        "a chaos soak: faults injected while jobs flow, safety checked",
    ),
    "logins": (
        "gridfleet.bench.logins",
        "the stop's latency while strangers flood the broker with wrong passwords",
    ),
    "flood": (
        "gridfleet.bench.flood",
        "one operator account's flood of valid requests: step rate, answers, stop latency",
    ),
    "history": (
        "gridfleet.bench.history",
        "the job history's store with a year of jobs: how fast its queries are answered",
    ),
    "vda5050": (
        "gridfleet.bench.vda5050",
        "a mixed fleet with VDA 5050 vehicles: jobs a minute, stop to every vehicle paused",
    ),
    "api": (
        "gridfleet.bench.api",
        "the HTTP API with a fleet moving: requests a second, and their cost to the step rate",
    ),
    "codec": (
        "gridfleet.bench.codec",
        "the hot path's messages read and written: pydantic beside orjson and msgspec",
    ),
    "energy": (
        "gridfleet.bench.energy",
        "throughput on batteries: our energy policy, a naive one and endless batteries",
    ),
}


class _BenchParser(GridfleetParser):
    """A bench's parser whose module is imported only when that bench is chosen (or its help is
    asked for): each bench module pulls in its own stack (scipy, playwright, psutil), and every
    `gridfleet bench` command would otherwise pay for all six before parsing a flag."""

    def __init__(self, *args: Any, module_name: str = "", **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._module_name: str | None = module_name or None
        self._missing: str | None = None

    def _load(self) -> None:
        name, self._module_name = self._module_name, None
        if name is None:
            return
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name not in BENCH_EXTRA:
                raise
            self._missing = exc.name  # still listed; run with any flags, it says what to install
            return
        module.add_arguments(self)

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> tuple[Any, list[str]]:
        """The bench's own flags, parsed once its module is in; any flags when it cannot be."""
        self._load()
        if self._missing is not None:
            namespace = argparse.Namespace() if namespace is None else namespace
            namespace.bench_missing = self._missing
            return namespace, []
        return super().parse_known_args(args, namespace)

    def format_help(self) -> str:
        """The bench's help, with its flags."""
        self._load()
        return super().format_help()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add one subcommand per benchmark."""
    sub = parser.add_subparsers(
        dest="bench", metavar="<bench>", required=True, parser_class=_BenchParser
    )
    for name, (module_name, help_text) in BENCHES.items():
        description = help_text[0].upper() + help_text[1:]
        sub.add_parser(name, help=help_text, description=description, module_name=module_name)


def run(args: argparse.Namespace) -> int:
    """Run the chosen benchmark."""
    missing = getattr(args, "bench_missing", None)
    if missing is not None:
        raise ConfigError(
            f"bench {args.bench} needs {missing}, of the bench extra: pip install 'gridfleet[bench]' "
            "(in a checkout, make install has it)"
        )
    module = importlib.import_module(BENCHES[args.bench][0])
    return int(module.run(args) or 0)
