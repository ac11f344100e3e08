"""`gridfleet bench energy`: throughput on batteries, three arms side by side in one run.

One scenario (default maps/warehouse-energy.toml), each seed (the coordinator's tie-breaking
seed) run three ways in turn, in `simulate --deterministic`'s lockstep engine (system/lockstep.py):
our energy policy ("gridfleet"), the naive one ("naive": to the nearest charger only at critical,
charged to full, no check that a job can be finished) and endless batteries (the same scenario
with every unit's battery taken out: the coordinator then sees no energy, as before issue 54).
A run ends when every job is final or at `--max-steps`. Reported per run and as medians per arm:
jobs done, steps, jobs per 1,000 steps, unit-steps charging (the batteries' own count), on the
way to a charger, queued for one and stranded (the coordinator's energy view, each step), units
that reached 0 %, the lowest charge, collisions, jobs given back for the battery; and the ratios
of our jobs per 1,000 steps to the naive policy's and to endless batteries'. A run that does not
finish counts every step of the budget, so a naive run that strands its units looks the worse
the larger the budget: two comparisons no budget changes come with it, the jobs each arm had
done in the steps our run took, and the rate counted only to each run's last job done.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from bisect import bisect_right
from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from gridfleet.config import check_step
from gridfleet.errors import ConfigError
from gridfleet.scenario import Scenario, load_scenario, with_units
from gridfleet.shipped import shipped_file
from gridfleet.system.lockstep import Lockstep

DEFAULT_SCENARIO = shipped_file("warehouse-energy", ".toml")
DEFAULT_STEP_S = 0.02  # simulate --deterministic's default (a battery's step is the same anyway)
ARMS: tuple[str, ...] = ("gridfleet", "naive", "endless")
ARM_WORDS = {
    "gridfleet": "our policy",
    "naive": "to the nearest charger only at critical, to full, no check that a job can be finished",
    "endless": "endless batteries: every unit's battery taken out",
}
PLANS = ("to_charger", "queued", "charging", "stranded")  # the energy view's plans


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet bench energy`."""
    parser.add_argument(
        "--scenario",
        default=str(DEFAULT_SCENARIO),
        help="a scenario with batteries and chargers, a file or a shipped name "
        "(default warehouse-energy)",
    )
    parser.add_argument("--seeds", type=int, default=5, help="seeds to run (default 5)")
    parser.add_argument(
        "--first-seed", type=int, default=0, help="the first seed; the others follow (default 0)"
    )
    parser.add_argument(
        "--max-steps",
        type=int,
        default=5000,
        help="a run's step budget: a run not finished by then ends there (default 5000)",
    )
    parser.add_argument(
        "--step",
        type=float,
        default=DEFAULT_STEP_S,
        help=f"the step period in seconds (default {DEFAULT_STEP_S}; steps are simulated)",
    )
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")


@dataclass(frozen=True)
class EnergyRun:
    """What one run of one arm did."""

    arm: str
    seed: int
    finished: bool  # every job final within the budget
    jobs: int
    jobs_done: int
    jobs_failed: int  # final but not done (cancelled, rejected, failed)
    jobs_left: int  # not final when the budget ran out
    steps: int  # steps run: to the last job final, or the budget
    last_done_step: int | None  # the step the last job done was done
    jobs_per_1000_steps: float  # jobs done / steps x 1000
    # jobs done / last_done_step x 1000: the rate while it still did jobs, whatever the budget
    # (a policy that strands its units looks best by this one)
    jobs_per_1000_steps_to_last_done: float | None
    charging_unit_steps: int  # steps the units' batteries charged, all units together
    to_charger_unit_steps: int  # unit-steps on the way to a charger (the energy view's plan)
    queued_unit_steps: int  # unit-steps waiting for a charger: every one busy
    stranded_unit_steps: int  # unit-steps no charger could help
    charges: int  # spells of charging, all units together
    units_with_battery: int
    units_empty: int  # units whose battery ever reached 0 %
    lowest_pct: float | None  # the lowest charge any unit had (None: no batteries)
    collisions: int
    jobs_requeued_for_battery: int  # jobs given back to the queue: their unit had to charge
    wall_s: float  # this machine's time for the run (reported, never judged)
    done_steps: tuple[int, ...] = field(default=(), repr=False)  # each job's done step, sorted

    def done_by(self, step: int) -> int:
        """Jobs this run had done by `step`."""
        return bisect_right(self.done_steps, step)

    def as_json(self) -> dict[str, Any]:
        """Its figures (without the done steps)."""
        out = asdict(self)
        del out["done_steps"]
        return out


def endless(scenario: Scenario) -> Scenario:
    """`scenario` with every unit's battery taken out: no unit reports energy."""
    return replace(scenario, units=tuple(replace(u, battery=None) for u in scenario.units))


def run_arm(scenario: Scenario, arm: str, seed: int, step_s: float, max_steps: int) -> EnergyRun:
    """One run of `arm` on `scenario`, in lockstep, to the end or `max_steps`."""
    if arm not in ARMS:
        raise ConfigError(f"arm {arm!r}: one of {', '.join(ARMS)}")
    started = time.monotonic()
    ran = endless(scenario) if arm == "endless" else scenario
    sim = Lockstep(ran, step_s, seed, policy="naive" if arm == "naive" else "gridfleet")
    sim.start()
    sim.submit_scenario()
    energy = sim.core.energy
    plans: Counter[str] = Counter()
    requeued = 0
    while sim.core.step_no < max_steps and not sim.finished():
        sim.step()
        plans.update(u.plan for u in energy.units_view().values())
        requeued += len(energy.last.requeue)
    jobs = list(sim.core.jobs.jobs.values())
    done = [j for j in jobs if j.state == "done"]
    batteries = [u.logic.battery for u in sim.units if u.logic.battery is not None]
    steps = sim.core.step_no
    last = max((j.done_step for j in done if j.done_step is not None), default=None)
    return EnergyRun(
        arm=arm,
        seed=seed,
        finished=sim.finished(),
        jobs=len(jobs),
        jobs_done=len(done),
        jobs_failed=sum(1 for j in jobs if j.final and j.state != "done"),
        jobs_left=sum(1 for j in jobs if not j.final),
        steps=steps,
        last_done_step=last,
        jobs_per_1000_steps=round(1000 * len(done) / steps, 2) if steps else 0.0,
        jobs_per_1000_steps_to_last_done=round(1000 * len(done) / last, 2) if last else None,
        charging_unit_steps=sum(b.charging_steps for b in batteries),
        to_charger_unit_steps=plans["to_charger"],
        queued_unit_steps=plans["queued"],
        stranded_unit_steps=plans["stranded"],
        charges=sum(b.charges for b in batteries),
        units_with_battery=len(batteries),
        units_empty=sum(1 for b in batteries if b.reached_empty),
        lowest_pct=round(min(b.lowest_pct for b in batteries), 1) if batteries else None,
        collisions=sim.world.collisions,
        jobs_requeued_for_battery=requeued,
        wall_s=round(time.monotonic() - started, 2),
        done_steps=tuple(sorted(j.done_step for j in done if j.done_step is not None)),
    )


def _median(values: list[Any], digits: int = 2) -> float | None:
    numbers = [v for v in values if v is not None]
    return round(statistics.median(numbers), digits) if numbers else None


def medians(runs: list[EnergyRun]) -> dict[str, dict[str, Any]]:
    """Per arm: the median of every figure over its runs, and how many runs finished."""
    out: dict[str, dict[str, Any]] = {}
    for arm in ARMS:
        mine = [r.as_json() for r in runs if r.arm == arm]
        if not mine:
            continue
        row: dict[str, Any] = {"runs": len(mine), "finished": sum(r["finished"] for r in mine)}
        for key in mine[0]:
            if key not in ("arm", "seed", "finished"):
                row[key] = _median([r[key] for r in mine])
        lows = [r["lowest_pct"] for r in mine if r["lowest_pct"] is not None]
        row["lowest_pct_of_all"] = min(lows) if lows else None
        out[arm] = row
    return out


def at_our_steps(runs: list[EnergyRun]) -> list[dict[str, Any]]:
    """Per seed: the jobs each arm had done in the steps our run took (to its end), a
    comparison no step budget changes."""
    out = []
    for ours in (r for r in runs if r.arm == "gridfleet"):
        row: dict[str, Any] = {"seed": ours.seed, "steps": ours.steps}
        for r in runs:
            if r.seed == ours.seed:
                row[r.arm] = r.done_by(ours.steps)
        out.append(row)
    return out


def ratio(ours: float | None, other: float | None) -> float | None:
    """ours / other (None when either is missing, or other is 0)."""
    if ours is None or other is None or other == 0:
        return None
    return round(ours / other, 3)


def report(scenario: Scenario, args: argparse.Namespace, runs: list[EnergyRun]) -> dict[str, Any]:
    """Every run, the medians per arm and the two ratios, as the JSON shape."""
    per_arm = medians(runs)

    def rate(arm: str, key: str = "jobs_per_1000_steps") -> float | None:
        return per_arm.get(arm, {}).get(key)

    to_last = "jobs_per_1000_steps_to_last_done"
    at_ours = at_our_steps(runs)

    return {
        "scenario": scenario.name,
        "units": len(scenario.units),
        "chargers": len(scenario.chargers),
        "jobs": len(scenario.jobs),
        "seeds": list(range(args.first_seed, args.first_seed + args.seeds)),
        "max_steps": args.max_steps,
        "step_s": args.step,
        "runs": [r.as_json() for r in runs],
        "at_ours_steps": at_ours,
        "medians": per_arm,
        "ours_over_naive": ratio(rate("gridfleet"), rate("naive")),
        "ours_over_endless": ratio(rate("gridfleet"), rate("endless")),
        "ours_over_naive_to_last_done": ratio(rate("gridfleet", to_last), rate("naive", to_last)),
        "ours_over_naive_at_ours_steps": _median(
            [ratio(s["gridfleet"], s["naive"]) for s in at_ours if "naive" in s], digits=3
        ),
    }


def check(scenario: Scenario, args: argparse.Namespace) -> None:
    """A scenario and flags the bench can run, or one clear ConfigError."""
    if args.seeds < 1 or args.max_steps < 1:
        raise ConfigError("--seeds and --max-steps must be at least 1")
    check_step(args.step)
    if not any(u.battery is not None for u in scenario.units):
        raise ConfigError(
            f"{scenario.path}: no unit has a battery (add [battery]): every arm would be the same"
        )
    if not scenario.chargers:
        raise ConfigError(f"{scenario.path}: no chargers (add [[chargers]])")
    if not scenario.jobs:
        raise ConfigError(f"{scenario.path}: no jobs to measure throughput on (add [[jobs]])")


def run(args: argparse.Namespace) -> int:
    """Run every seed's three arms in turn and print; exit 1 when a run collided or a unit under
    our policy ran empty (the naive policy may strand units: that is what it is measured for)."""
    scenario = with_units(load_scenario(args.scenario))
    check(scenario, args)
    runs: list[EnergyRun] = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        for arm in ARMS:
            one = run_arm(scenario, arm, seed, args.step, args.max_steps)
            runs.append(one)
            print(f"bench energy: seed {seed} {arm}: {_line(one)}", file=sys.stderr, flush=True)
    figures = report(scenario, args, runs)
    if args.json:
        print(json.dumps(figures))
    else:
        _print_tables(figures)
    broken = any(r.collisions for r in runs) or any(
        r.units_empty for r in runs if r.arm == "gridfleet"
    )
    return 1 if broken else 0


def _line(r: EnergyRun) -> str:
    """One run in words, for the progress on stderr."""
    end = "finished" if r.finished else "budget reached"
    return (
        f"{r.jobs_done}/{r.jobs} jobs in {r.steps} steps ({end}), "
        f"{r.jobs_per_1000_steps:.1f} per 1,000 steps, {r.units_empty} empty, {r.wall_s:.1f} s"
    )


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.0f}" if value.is_integer() or abs(value) >= 1000 else f"{value:.1f}"
    return str(value)


def _table(rows: list[dict[str, Any]], keys: list[tuple[str, str]]) -> None:
    cells = [[_fmt(row.get(k)) for k, _ in keys] for row in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, (_, h) in enumerate(keys)]
    print("  " + "  ".join(h.rjust(w) for (_, h), w in zip(keys, widths, strict=True)))
    for c in cells:
        print("  " + "  ".join(v.rjust(w) for v, w in zip(c, widths, strict=True)))


COLUMNS = [
    ("jobs_done", "done"),
    ("steps", "steps"),
    ("jobs_per_1000_steps", "jobs/1000 steps"),
    ("last_done_step", "last done"),
    ("jobs_per_1000_steps_to_last_done", "to last done"),
    ("charging_unit_steps", "charging"),
    ("queued_unit_steps", "queued"),
    ("to_charger_unit_steps", "to charger"),
    ("stranded_unit_steps", "stranded"),
    ("units_empty", "empty"),
    ("lowest_pct", "lowest %"),
    ("collisions", "collisions"),
    ("jobs_requeued_for_battery", "requeued"),
    ("wall_s", "wall s"),
]


def _print_tables(figures: dict[str, Any]) -> None:
    print(
        f"{figures['scenario']}: {figures['units']} units, {figures['chargers']} chargers, "
        f"{figures['jobs']} jobs; seeds {', '.join(map(str, figures['seeds']))}, "
        f"budget {figures['max_steps']} steps (lockstep, deterministic)"
    )
    print("\nevery run (charging, queued, to charger, stranded: unit-steps)")
    _table(figures["runs"], [("seed", "seed"), ("arm", "arm"), ("finished", "finished"), *COLUMNS])
    print("\nmedians per arm")
    rows = [
        {"arm": arm, **row, "finished": f"{row['finished']} of {row['runs']}"}
        for arm, row in figures["medians"].items()
    ]
    _table(rows, [("arm", "arm"), ("finished", "finished"), *COLUMNS])
    lows = [
        f"{arm} {_fmt(row['lowest_pct_of_all'])} %"
        for arm, row in figures["medians"].items()
        if row["lowest_pct_of_all"] is not None
    ]
    print("  lowest charge of all runs: " + ", ".join(lows))
    for arm, words in ARM_WORDS.items():
        print(f"  {arm}: {words}")
    print("\njobs done in the steps our run took, per seed")
    _table(
        figures["at_ours_steps"],
        [("seed", "seed"), ("steps", "steps"), *((arm, arm) for arm in ARMS)],
    )
    print()
    over_endless = figures["ours_over_endless"]
    print(_against_naive(figures["ours_over_naive"], "jobs per 1,000 steps"))
    print(_against_naive(figures["ours_over_naive_at_ours_steps"], "jobs done in our steps"))
    to_last = figures["ours_over_naive_to_last_done"]
    if to_last is not None:
        print(
            f"counted only to each run's last job done: ours / naive = {to_last:.2f} "
            "(the naive runs' rate before their units ran empty)"
        )
    if over_endless is not None:
        print(f"ours reaches {100 * over_endless:.0f} % of endless batteries' jobs per 1,000 steps")
    unfinished = [
        f"{arm} {row['runs'] - row['finished']} of {row['runs']}"
        for arm, row in figures["medians"].items()
        if row["finished"] < row["runs"]
    ]
    if unfinished:
        print(
            "not finished within the budget (their steps are the budget): " + ", ".join(unfinished)
        )


def _against_naive(value: float | None, measure: str) -> str:
    """Ours against naive by `measure`, in words."""
    if value is None:
        return f"ours against naive ({measure}): no ratio (naive did no job)"
    if value >= 1:
        return f"ours beats naive by {100 * (value - 1):.0f} % ({measure})"
    return f"ours is {100 * (1 - value):.0f} % below naive ({measure})"
