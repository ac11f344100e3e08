"""The `gridfleet` command: one subcommand per component, each defined in its own module.

Each subcommand module exposes `add_arguments(parser)` and `run(args) -> int`; it is imported
only when its command runs, so `gridfleet --help` stays fast and components stay independent.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from types import ModuleType

import aiomqtt

from gridfleet import __version__
from gridfleet.config import redacted
from gridfleet.errors import GridfleetError
from gridfleet.lifeline import die_with_parent
from gridfleet.options import GridfleetParser

COMMANDS: dict[str, tuple[str, str]] = {
    "up": ("gridfleet.system.up", "start everything: broker, coordinator, units and dashboard"),
    "broker": ("gridfleet.broker.cli", "run the embedded MQTT broker (amqtt)"),
    "coordinator": (
        "gridfleet.coordinator.cli",
        "run the coordinator: world model, jobs, planning",
    ),
    "robots": ("gridfleet.robots.cli", "run the simulated units of a scenario"),
    "dashboard": ("gridfleet.dashboard.cli", "serve the browser dashboard"),
    "device": ("gridfleet.device.cli", "a virtual ESP32: direction LEDs and an emergency-stop key"),
    "job": ("gridfleet.console.job", "submit, cancel and list jobs; set goals; emergency stop"),
    "audit": ("gridfleet.console.audit", "who did what and when: the audit trail of operator acts"),
    "feed": (
        "gridfleet.console.feed",
        "submit a scenario's jobs and goals; --demo keeps jobs coming",
    ),
    "simulate": ("gridfleet.system.simulate", "run a scenario to the end in accelerated time"),
    "accounts": (
        "gridfleet.system.accounts_cli",
        "make the broker accounts file; add accounts to it",
    ),
    "clean": ("gridfleet.console.clean", "clear a topic root's retained messages on a broker"),
    "status": (
        "gridfleet.console.status",
        "the fleet at a glance: the stop, the coordinator, units, jobs",
    ),
    "bench": ("gridfleet.bench.cli", "benchmark the planner and the whole system"),
    "webots-world": ("gridfleet.robots.webots.cli", "write a Webots world (.wbt) for a scenario"),
    "vda5050": (
        "gridfleet.robots.vda5050.cli",
        "run VDA 5050 vehicles (a vehicles file) as units of the fleet",
    ),
    "alerts": (
        "gridfleet.alerts.cli",
        "raise and clear alerts (webhook, metrics); --list shows them, --ack ID acknowledges one",
    ),
}


def _load(command: str) -> ModuleType | None:
    module_name = COMMANDS[command][0]
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and module_name.startswith(exc.name):
            return None
        raise


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The argument parser; with `only`, just that subcommand's module is imported."""
    parser = GridfleetParser(
        prog="gridfleet",
        description="gridfleet: a connected robot fleet on a grid playfield, over MQTT.",
        epilog="Run 'gridfleet <command> --help' for a command's options.",
    )
    parser.add_argument("--version", action="version", version=f"gridfleet {__version__}")
    parser.add_argument(
        "--log-level",
        default="INFO",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="default INFO",
    )
    sub = parser.add_subparsers(dest="command", metavar="<command>", parser_class=GridfleetParser)
    for name, (_, help_text) in COMMANDS.items():
        cmd = sub.add_parser(name, help=help_text, description=help_text[0].upper() + help_text[1:])
        if name == only:
            module = _load(name)
            if module is not None:
                module.add_arguments(cmd)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script."""
    die_with_parent()  # started by `gridfleet up` (or another supervisor): end with it
    args_list = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in args_list if a in COMMANDS), None)
    parser = build_parser(only=command)
    args = parser.parse_args(args_list)
    if args.command is None:
        parser.print_help()
        return 2
    logging.basicConfig(
        level=args.log_level, format="%(asctime)s %(levelname)-7s %(name)s: %(message)s"
    )
    if args.log_level != "DEBUG":
        # amqtt narrates every state change at INFO; only our own INFO lines help an operator.
        for noisy in ("amqtt", "transitions", "websockets", "werkzeug"):
            logging.getLogger(noisy).setLevel(logging.WARNING)
    module = _load(args.command)
    if module is None:
        print(f"gridfleet {args.command}: not available in this build", file=sys.stderr)
        return 2
    try:
        return int(module.run(args) or 0)
    except GridfleetError as exc:
        print(f"gridfleet {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except aiomqtt.MqttError as exc:
        # One-shot commands (job, simulate with --broker) fail fast; services retry on their own.
        where = redacted(getattr(args, "broker", None) or "the broker")
        print(f"gridfleet {args.command}: error: MQTT with {where}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader went away (`gridfleet job list | head`): stop quietly, as `ls` would.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell reports for a writer killed by it


if __name__ == "__main__":
    sys.exit(main())
