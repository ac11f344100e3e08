"""`gridfleet bench system`: the whole system over a real broker, per unit count, medians."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import sys
from typing import Any, TextIO

from gridfleet.bench.system.result import SystemResult, summarise
from gridfleet.bench.system.run import run_system
from gridfleet.config import check_step, parse_brokers
from gridfleet.coordinator.window import DEFAULT_WINDOW, MAX_WINDOW
from gridfleet.errors import ConfigError
from gridfleet.tasks import stop_on_signals


def unit_counts(text: str) -> list[int]:
    """`50,100,200` → [50, 100, 200]; argparse turns the error into a usage line."""
    try:
        counts = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a list of unit counts") from None
    if not counts:
        raise argparse.ArgumentTypeError("give at least one unit count")
    return counts


def window_list(text: str) -> list[int]:
    """`4` or `1,4`: the windows to run, each 1 to MAX_WINDOW (ConfigError otherwise)."""
    try:
        windows = [int(part) for part in text.split(",")]
    except ValueError:
        raise ConfigError(f"--windows {text}: not a list of windows, e.g. 1,4") from None
    if any(not 1 <= w <= MAX_WINDOW for w in windows):
        raise ConfigError(f"--windows {text}: each window is 1 to {MAX_WINDOW} squares")
    return windows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet bench system`."""
    parser.add_argument(
        "--units", type=unit_counts, default=[50, 100, 200], help="unit counts (default 50,100,200)"
    )
    parser.add_argument("--step", type=float, default=0.1, help="step period, s (default 0.1)")
    parser.add_argument(
        "--duration", type=float, default=10.0, help="measured seconds per run (default 10)"
    )
    parser.add_argument(
        "--warmup", type=float, help="seconds before measuring (default max(1, 10 steps))"
    )
    parser.add_argument("--repeat", type=int, default=3, help="runs per unit count (default 3)")
    parser.add_argument(
        "--estops", type=int, default=3, help="stop engagements per run (default 3)"
    )
    parser.add_argument(
        "--broker",
        help="broker URL, e.g. mqtt://127.0.0.1:1883, or a comma-separated list of a cluster's "
        "nodes (default: embedded amqtt)",
    )
    parser.add_argument("--seed", type=int, default=0, help="map, starts and jobs (default 0)")
    parser.add_argument(
        "--deploy",
        choices=["processes", "threads"],
        default="processes",
        help="processes: broker, coordinator and unit workers each in their own, as deployed "
        "(default); threads: coordinator and units in threads of the bench",
    )
    parser.add_argument(
        "--workers",
        type=int,
        help="unit processes (default: one per 50 units, at most one per core)",
    )
    parser.add_argument(
        "--windows",
        default=str(DEFAULT_WINDOW),
        metavar="N[,N...]",
        help=f"the coordinator's --window (default {DEFAULT_WINDOW}); several are run in turn, "
        "alternating within each repeat, to compare them side by side",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def check(args: argparse.Namespace) -> None:
    """One clear line (ConfigError) for each bad flag, before anything starts."""
    bad = [n for n in args.units if n < 1]
    if bad:
        raise ConfigError(f"--units {bad[0]}: every unit count must be at least 1")
    check_step(args.step)
    if not args.duration > 0:
        raise ConfigError(f"--duration {args.duration}: give a positive number of seconds")
    if args.warmup is not None and not args.warmup >= 0:
        raise ConfigError(f"--warmup {args.warmup}: give zero or more seconds")
    if args.repeat < 1:
        raise ConfigError(f"--repeat {args.repeat}: give at least 1")
    if args.estops < 1:
        raise ConfigError(f"--estops {args.estops}: give at least 1")
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers {args.workers}: give at least 1")
    if args.workers not in (None, 1) and args.deploy == "threads":
        raise ConfigError("--workers: unit workers are processes, not with --deploy threads")
    if args.broker is not None:
        parse_brokers(args.broker)
    if isinstance(args.windows, str):
        args.windows = window_list(args.windows)


def _cell(summary: dict[str, Any], name: str, fmt: str) -> str:
    value = summary[name]
    if value is None:
        return "-"
    if not isinstance(value, dict):
        return format(value, fmt)
    text = format(value["median"], fmt)
    if value["min"] != value["max"]:
        text += f" ({format(value['min'], fmt)}-{format(value['max'], fmt)})"
    return text


COLUMNS = (
    ("units", "units", "d"),
    ("window", "window", "d"),
    ("msgs/s", "messages_per_s", ".0f"),
    ("steps/s", "step_rate", ".2f"),
    ("moves/unit/s", "moves_per_unit_s", ".2f"),
    ("jobs done", "jobs_done", ".0f"),
    ("state p50 ms", "state_latency_ms_p50", ".1f"),
    ("state p99 ms", "state_latency_ms_p99", ".1f"),
    ("estop ms", "estop_ms_median", ".1f"),
    ("estop p99 ms", "estop_ms_p99", ".1f"),
    ("collisions", "collisions", "d"),
    ("prevented", "prevented", ".0f"),
)


def print_table(summaries: list[dict[str, Any]], out: TextIO) -> None:
    """Medians per unit count, with the (min-max) spread when the runs differ."""
    rows = [[title for title, _, _ in COLUMNS]]
    rows += [[_cell(s, name, fmt) for _, name, fmt in COLUMNS] for s in summaries]
    widths = [max(len(r[i]) for r in rows) for i in range(len(COLUMNS))]
    for row in rows:
        print("  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)), file=out)


async def _bench(args: argparse.Namespace, results: list[list[SystemResult]]) -> None:
    for units in args.units:
        by_window: dict[int, list[SystemResult]] = {w: [] for w in args.windows}
        results.extend(by_window.values())
        for n, window in ((n, w) for n in range(args.repeat) for w in args.windows):
            runs = by_window[window]
            result = await run_system(
                units,
                args.step,
                args.duration,
                seed=args.seed + n,
                broker_url=args.broker,
                estops=args.estops,
                warmup_s=args.warmup,
                deploy=args.deploy,
                workers=args.workers,
                window=window,
            )
            runs.append(result)
            if not args.json:
                print(
                    f"  {units} units, window {window}, run {n + 1}/{args.repeat}: "
                    f"{result.messages_per_s:.0f} msg/s,"
                    f" {result.step_rate:.2f} steps/s, estop {result.estop_ms_median} ms",
                    file=sys.stderr,
                    flush=True,
                )
                for p in result.processes:
                    print(
                        f"    {p.name}: {p.cpu_pct:.0f} % of a core, peak {p.peak_rss_mb:.0f} MB",
                        file=sys.stderr,
                        flush=True,
                    )


async def _main(args: argparse.Namespace, results: list[list[SystemResult]]) -> bool:
    """True when the bench ran to the end; False when Ctrl-C stopped it (cleanly)."""
    stop = stop_on_signals()
    work = asyncio.create_task(_bench(args, results))
    stopper = asyncio.create_task(stop.wait())
    await asyncio.wait({work, stopper}, return_when=asyncio.FIRST_COMPLETED)
    stopper.cancel()
    if stop.is_set() and not work.done():
        # One cancellation: it ends the wait under way and lets every cleanup run to its end
        # (services stopped before their broker), which a repeated cancel would cut short.
        work.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await work
        return False
    work.result()
    return True


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet bench system`."""
    check(args)
    # The components log every warning; the bench's output is its table (or its JSON).
    # Overload warnings (pending publishes, late states) are what the figures already show.
    logging.disable(logging.WARNING)
    results: list[list[SystemResult]] = []
    finished = asyncio.run(_main(args, results))
    summaries = [summarise(runs) for runs in results if runs]
    if args.json:
        keys = ("units", "step", "duration", "repeat", "seed", "deploy", "workers", "windows")
        config = {k: getattr(args, k) for k in keys}
        config["broker"] = args.broker or "embedded amqtt"
        output = {
            "config": config,
            "finished": finished,
            "runs": [r.as_json() for runs in results for r in runs],
            "summary": summaries,
        }
        json.dump(output, sys.stdout)
        sys.stdout.write("\n")
    else:
        broker = args.broker or "embedded amqtt (a process of its own)"
        print(
            f"system bench: step {args.step} s, {args.duration} s measured, broker {broker}, "
            f"deployed as {args.deploy}"
        )
        print_table(summaries, sys.stdout)
        if not finished:
            print("interrupted: the table shows the runs that finished")
    unsafe = any(s["collisions"] or s["moved_while_stopped"] for s in summaries)
    return 130 if not finished else (1 if unsafe else 0)
