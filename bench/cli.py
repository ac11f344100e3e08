"""`gridfleet bench`: run one of the benchmarks and report medians."""

from __future__ import annotations

import argparse
import importlib

from gridfleet.errors import ConfigError

# What pyproject's `bench` extra brings; a bench that needs one missing says how to install it.
BENCH_EXTRA = {"psutil", "playwright", "matplotlib"}

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
    "vda5050": (
        "gridfleet.bench.vda5050",
        "a mixed fleet with VDA 5050 vehicles: jobs a minute, stop to every vehicle paused",
    ),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add one subcommand per benchmark."""
    sub = parser.add_subparsers(dest="bench", metavar="<bench>", required=True)
    for name, (module_name, help_text) in BENCHES.items():
        description = help_text[0].upper() + help_text[1:]
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name not in BENCH_EXTRA:
                raise
            # Still listed; run with any flags, it says what to install (no flag is parsed: the
            # parser's prefix character never occurs).
            cmd = sub.add_parser(
                name, help=help_text, description=description, prefix_chars="\0", add_help=False
            )
            cmd.set_defaults(bench_missing=exc.name)
            cmd.add_argument("flags", nargs="*")
            continue
        cmd = sub.add_parser(name, help=help_text, description=description)
        module.add_arguments(cmd)


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
