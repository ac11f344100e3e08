"""`gridfleet bench page`: the dashboard's frame budget at fleet scale, and its cost to the fleet."""

from __future__ import annotations

import argparse
from pathlib import Path

from gridfleet.bench.page import report, run_page_bench
from gridfleet.config import check_step
from gridfleet.errors import ConfigError


def _viewport(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT, e.g. 1280x800") from None
    if w < 320 or h < 240:
        raise argparse.ArgumentTypeError(f"{text!r}: at least 320x240")
    return w, h


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet bench page`."""
    parser.add_argument("--units", type=int, default=150, help="units (default 150)")
    parser.add_argument(
        "--jobs", type=int, default=450, help="jobs queued at the start (default 450)"
    )
    parser.add_argument("--step", type=float, default=0.2, help="step period, s (default 0.2)")
    parser.add_argument(
        "--phase", type=float, default=20.0, help="seconds of each closed and open phase (20)"
    )
    parser.add_argument(
        "--warmup", type=float, default=20.0, help="seconds before the first phase (default 20)"
    )
    parser.add_argument("--phases", type=int, default=3, help="closed/open pairs (default 3)")
    parser.add_argument(
        "--viewport", type=_viewport, default=(1280, 800), help="WIDTHxHEIGHT (1280x800)"
    )
    parser.add_argument("--screenshot", type=Path, help="save the page as PNG after each phase")
    parser.add_argument("--json", action="store_true", help="print JSON")


def run(args: argparse.Namespace) -> int:
    """Run the bench and print its figures."""
    check_step(args.step)
    if args.units < 1 or args.jobs < 0 or args.phases < 1 or args.phase < 5 or args.warmup < 0:
        raise ConfigError("--units ≥ 1, --jobs ≥ 0, --phases ≥ 1, --phase ≥ 5, --warmup ≥ 0")
    result = run_page_bench(
        args.units,
        args.jobs,
        args.step,
        args.phase,
        args.phases,
        args.viewport,
        args.screenshot,
        warmup_s=args.warmup,
    )
    print(report(result, args.json))
    return 0
