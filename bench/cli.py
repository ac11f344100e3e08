"""`gridfleet bench`: run one of the benchmarks and report medians."""

from __future__ import annotations

import argparse
import importlib

# name -> (module, help). Each module offers add_arguments(parser) and run(args) -> int.
BENCHES: dict[str, tuple[str, str]] = {
    "planner": (
        "gridfleet.bench.planner_cli",
        "the planner alone on public MAPF instances (no broker)",
    ),
    "system": (
        "gridfleet.bench.system_cli",
        "the whole system over a real broker: throughput, stop latency",
    ),
    "page": (
        "gridfleet.bench.page_cli",
        "the dashboard in Chromium at fleet scale: frame budget, fleet cost",
    ),
    "soak": (
        "gridfleet.bench.soak_cli",
        "a chaos soak: faults injected while jobs flow, safety checked",
    ),
    "logins": (
        "gridfleet.bench.logins",
        "the stop's latency while strangers flood the broker with wrong passwords",
    ),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add one subcommand per benchmark."""
    sub = parser.add_subparsers(dest="bench", metavar="<bench>", required=True)
    for name, (module_name, help_text) in BENCHES.items():
        module = importlib.import_module(module_name)
        cmd = sub.add_parser(name, help=help_text, description=help_text[0].upper() + help_text[1:])
        module.add_arguments(cmd)


def run(args: argparse.Namespace) -> int:
    """Run the chosen benchmark."""
    module = importlib.import_module(BENCHES[args.bench][0])
    return int(module.run(args) or 0)
