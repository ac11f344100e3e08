"""`gridfleet bench planner`: the planner alone on public MAPF instances, medians reported."""

from __future__ import annotations

import argparse
import json
import logging
import resource
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, TypeVar

from gridfleet.bench.anchors import (
    LifelongInstance,
    find_anchors,
    lifelong_instances,
    load_instance,
    load_scen,
)
from gridfleet.bench.plot import check_plot_target, plot_report
from gridfleet.bench.runs import (
    GUIDANCE,
    LifelongResult,
    OneShotResult,
    Timing,
    run_lifelong,
    run_one_shot,
)
from gridfleet.bench.scale import run_scale
from gridfleet.errors import ConfigError
from gridfleet.maps import load_map

log = logging.getLogger("gridfleet.bench")

SUITES = ("lifelong", "oneshot", "scale")
CHECKPOINTS = (1000, 2500)  # ticks at which an --instance run reports the tasks finished so far
SCEN = "random-32-32-10-random-1.scen"
R = TypeVar("R", LifelongResult, OneShotResult)


def _counts(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected whole numbers like 50,100, got {text!r}"
        ) from None
    if not values or any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(f"expected counts of at least 1, got {text!r}")
    return values


def _positive(text: str) -> int:
    values = _counts(text)
    if len(values) != 1:
        raise argparse.ArgumentTypeError(f"expected one whole number, got {text!r}")
    return values[0]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet bench planner`."""
    parser.add_argument(
        "--anchors",
        help="benchmark data folder (default $GRIDFLEET_ANCHORS, else shared/anchors beside "
        "the checkout)",
    )
    parser.add_argument(
        "--suite",
        default=",".join(SUITES),
        help=f"which runs, comma-separated (default {','.join(SUITES)})",
    )
    parser.add_argument(
        "--instances", help="lifelong instances by name, comma-separated (default: all)"
    )
    parser.add_argument(
        "--instance",
        type=Path,
        action="append",
        help="run this lifelong instance file instead of the suites (its map: maps/ beside its "
        "folder, or --anchors' maps/); may be given more than once",
    )
    parser.add_argument(
        "--horizon", type=_positive, help="cap every lifelong run at this many ticks"
    )
    parser.add_argument(
        "--agents",
        type=_counts,
        default=[50, 100, 200, 400],
        help="one-shot agent counts (default 50,100,200,400)",
    )
    parser.add_argument("--scen", default=SCEN, help=f"one-shot Moving AI scenario ({SCEN})")
    parser.add_argument("--scale-map", default="warehouse_large.map", help="map of the scale run")
    parser.add_argument(
        "--scale-agents", type=_counts, default=[10_000], help="agents of the scale run (10000)"
    )
    parser.add_argument("--scale-ticks", type=_positive, default=1000, help="ticks (1000)")
    parser.add_argument(
        "--scale-pick-faces", type=_positive, default=2000, help="squares jobs start at (2000)"
    )
    parser.add_argument(
        "--scale-stations", type=_positive, default=200, help="squares jobs end at (200)"
    )
    parser.add_argument(
        "--guidance",
        choices=list(GUIDANCE),
        default="auto",
        help="auto: as the coordinator (guide paths on maps up to 4096 squares, one-way lanes "
        "above); off: plain shortest-path fields; lanes; paths (default auto)",
    )
    parser.add_argument("--repeat", type=_positive, default=1, help="runs of each (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="planner and scale-run seed")
    parser.add_argument("--json", action="store_true", help="print JSON instead of tables")
    parser.add_argument(
        "--plot",
        type=Path,
        help="also draw throughput and tick time against agents (needs matplotlib)",
    )


def run(args: argparse.Namespace) -> int:
    """Run the chosen suites and print their medians."""
    suites = [s.strip() for s in args.suite.split(",") if s.strip()]
    unknown = sorted(set(suites) - set(SUITES))
    if unknown or not suites:
        raise ConfigError(f"--suite: unknown {unknown or suites} (known: {', '.join(SUITES)})")
    if args.plot:
        check_plot_target(args.plot)
    report: dict[str, list[dict[str, Any]]] = {}
    if args.instance:
        report["instance"] = [_instance(path, args) for path in args.instance]
        return _report(report, args)
    anchors = find_anchors(args.anchors)
    if "lifelong" in suites:
        report["lifelong"] = _lifelong(anchors, args)
    if "oneshot" in suites:
        report["oneshot"] = _oneshot(anchors, args)
    if "scale" in suites:
        report["scale"] = _scale(anchors, args)
    return _report(report, args)


def _report(report: dict[str, list[dict[str, Any]]], args: argparse.Namespace) -> int:
    """Draw, print, and say whether any plan broke a rule."""
    if args.plot:
        plot_report(report, args.plot)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        _print_tables(report)
    unsafe = sum(row["violations"] for rows in report.values() for row in rows)
    if unsafe:
        log.error("the planner made %d unsafe moves (see 'violations')", unsafe)
        return 1
    return 0


def _repeat(runs: int, once: Callable[[], R]) -> tuple[R, Timing]:
    """The first result and the timing of the run with the median median step time."""
    results = [once() for _ in range(runs)]
    by_median = sorted(results, key=lambda r: r.timing.median_ms)
    return results[0], by_median[len(by_median) // 2].timing


def _timing(t: Timing) -> dict[str, float]:
    return {"ms_p50": t.median_ms, "ms_p95": t.p95_ms, "ms_p99": t.p99_ms, "ms_max": t.max_ms}


def _lifelong(anchors: Path, args: argparse.Namespace) -> list[dict[str, Any]]:
    paths = lifelong_instances(anchors)
    if args.instances:
        wanted = [n.strip() for n in args.instances.split(",") if n.strip()]
        known = {p.stem: p for p in paths}
        missing = [n for n in wanted if n not in known]
        if missing:
            raise ConfigError(f"--instances: no {missing} in {anchors / 'instances'}")
        paths = [known[n] for n in wanted]
    rows = []
    for path in paths:
        instance = load_instance(path, anchors / "maps")
        log.info("lifelong %s: %d agents", instance.name, instance.agents)
        result, timing = _repeat(
            args.repeat,
            partial(run_lifelong, instance, args.horizon, seed=args.seed, guidance=args.guidance),
        )
        rows.append(
            {
                "instance": result.name,
                "agents": result.agents,
                "ticks": result.ticks,
                "tasks_finished": result.tasks_finished,
                "tasks_available": result.tasks_available,
                "stream_exhausted_at": result.exhausted_at,
                "best_in_competition": instance.best_tasks_finished,
                "competition_model": instance.action_model,
                "violations": result.violations,
                **_timing(timing),
            }
        )
    return rows


def _instance(path: Path, args: argparse.Namespace) -> dict[str, Any]:
    """One lifelong instance file, by path, under its own rule (MR24: the task pool)."""
    maps = Path(args.anchors) / "maps" if args.anchors else None
    instance = load_instance(path, maps)
    ticks = min(args.horizon or instance.horizon, instance.horizon)
    log.info(
        "%s: %d agents, %d of %d ticks", instance.name, instance.agents, ticks, instance.horizon
    )
    every = max(1, ticks // 20)

    def progress(tick: int, finished: int) -> None:
        if (tick + 1) % every == 0:
            log.info("%s: tick %d, %d tasks finished", instance.name, tick + 1, finished)

    result = run_lifelong(
        instance, ticks, seed=args.seed, progress=progress, guidance=args.guidance
    )
    return {**instance_row(instance, result, peak_rss_mb()), "guidance": args.guidance}


def instance_row(
    instance: LifelongInstance, result: LifelongResult, rss_mb: float
) -> dict[str, Any]:
    """The figures of a run of `instance`: tasks against the competition's best, tick times."""
    best, done, ticks, full = (
        instance.best_tasks_finished,
        result.tasks_finished,
        result.ticks,
        instance.horizon,
    )
    by_tick = result.finished_by_tick
    tail = max(1, ticks // 10)  # the rate at the end: the last tenth of the run
    end_rate = (by_tick[-1] - (by_tick[-tail - 1] if ticks > tail else 0)) / tail if ticks else 0.0
    early = ticks < full
    tick = result.tick
    later = Timing(tick.seconds[1:])
    row: dict[str, Any] = {
        "instance": result.name,
        "agents": result.agents,
        "ticks": ticks,
        "of_ticks": full,
        "tasks_finished": done,
        "best_in_competition": best,
        "ratio_to_best": done / best if best else None,
        **{f"finished_by_{t}": by_tick[t - 1] for t in CHECKPOINTS if t <= ticks},
        "tasks_per_tick_at_end": end_rate,
        # Stopped early: what the run would finish at the rate so far, and at its rate at the end
        # (projections, not measurements: congestion and the pool change over a run).
        "projected_linear": done * full / ticks if early and ticks else None,
        "projected_linear_ratio": done * full / ticks / best if early and ticks and best else None,
        "projected_end_rate": done + end_rate * (full - ticks) if early else None,
        "first_tick_s": result.setup_s + (tick.seconds[0] if tick.seconds else 0.0),
        "tick_ms_mean": later.mean_ms,
        "tick_ms_p99": later.p99_ms,
        "tick_ms_max": later.max_ms,
        "planner_ms_p50": Timing(result.timing.seconds[1:]).median_ms,
        "scheduler_ms_p50": Timing(result.scheduling.seconds[1:]).median_ms,
        "fields_computed": result.fields_computed,
        "peak_rss_mb": rss_mb,
        "competition_model": instance.action_model,
        "violations": result.violations,
    }
    return row


def _oneshot(anchors: Path, args: argparse.Namespace) -> list[dict[str, Any]]:
    grid, agents = load_scen(anchors / "maps" / args.scen)
    rows = []
    for n in args.agents:
        if n > len(agents):
            raise ConfigError(f"--agents: {args.scen} has {len(agents)} agents, not {n}")
        log.info("one-shot %s: %d agents", args.scen, n)
        result, timing = _repeat(
            args.repeat,
            partial(
                run_one_shot,
                grid,
                agents[:n],
                max_steps=1000,
                seed=args.seed,
                guidance=args.guidance,
            ),
        )
        ratio = result.sum_of_costs / result.lower_bound if result.sum_of_costs else None
        rows.append(
            {
                "agents": n,
                "solved": result.solved,
                "at_goal": result.at_goal,
                "makespan": result.makespan,
                "sum_of_costs": result.sum_of_costs,
                "lower_bound": result.lower_bound,
                "soc_over_lower_bound": ratio,
                "planning_s": sum(timing.seconds),
                "violations": result.violations,
                **_timing(timing),
            }
        )
    return rows


def _scale(anchors: Path, args: argparse.Namespace) -> list[dict[str, Any]]:
    grid = load_map(anchors / "maps" / args.scale_map)
    rows = []
    for n in args.scale_agents:
        log.info("scale %s: %d agents, %d ticks", grid.name, n, args.scale_ticks)
        once = partial(
            run_scale,
            grid,
            n,
            args.scale_ticks,
            seed=args.seed,
            pick_faces=args.scale_pick_faces,
            stations=args.scale_stations,
            guidance=args.guidance,
        )
        try:
            results = [once() for _ in range(args.repeat)]
        except ValueError as exc:
            raise ConfigError(f"--scale-agents: {exc}") from None
        result = sorted(results, key=lambda r: r.tick.median_ms)[len(results) // 2]
        rows.append(
            {
                "map": grid.name,
                "guidance": args.guidance,
                "agents": n,
                "ticks": result.ticks,
                "tasks_finished": result.tasks_finished,
                "tasks_per_tick": result.tasks_per_tick,
                "tasks_per_tick_second_half": result.steady_tasks_per_tick,
                "travel_per_job": result.travel_per_job,
                "first_tick_s": result.first_tick_s,
                "tick_ms_mean": result.tick.mean_ms,
                "tick_ms_p99": result.tick.p99_ms,
                "planner_ms_p50": result.planner.median_ms,
                "allocation_ms_p50": result.allocation.median_ms,
                "peak_rss_mb": peak_rss_mb(),
                "violations": result.violations,
                **_timing(result.tick),
            }
        )
    return rows


def peak_rss_mb() -> float:
    """The most memory this process has held so far, in MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _print_tables(report: dict[str, list[dict[str, Any]]]) -> None:
    titles = {
        "lifelong": "lifelong MAPF, League of Robot Runners instances (tasks finished in the "
        "horizon; the competition's robots turn in place (MAPF_T), ours move 4-connected)",
        "oneshot": "one-shot MAPF, Moving AI scenario (sum of costs over the no-other-agents bound)",
        "scale": "scale: pick-and-deliver jobs on a large map, allocated by the coordinator's "
        "allocator (first tick: every pick face's and station's distance field)",
        "instance": "lifelong instance files under their own rule (tick: planner and "
        "scheduler; projected_*: projections to the full horizon, not measured)",
    }
    for suite, rows in report.items():
        print(f"\n{titles[suite]}")
        if not rows:
            print("  (nothing to run)")
            continue
        keys = list(rows[0])
        cells = [[_fmt(row[k]) for k in keys] for row in rows]
        widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
        print("  " + "  ".join(k.rjust(w) for k, w in zip(keys, widths, strict=True)))
        for c in cells:
            print("  " + "  ".join(v.rjust(w) for v, w in zip(c, widths, strict=True)))
    print("\nms_*: planner time per step on this machine (the run with the median median)")


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.2f}" if value < 100 else f"{value:.0f}"
    return "-" if value is None else str(value)
