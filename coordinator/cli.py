"""`gridfleet coordinator`: run the coordinator (its shell, `CoordinatorShell`) on a map."""

from __future__ import annotations

import argparse
import asyncio
import math
from dataclasses import dataclass, field

from gridfleet.config import check_step
from gridfleet.coordinator.audit import DEFAULT_AUDIT_DAYS, Identity
from gridfleet.coordinator.energy import POLICIES, EnergySettings
from gridfleet.coordinator.history import DEFAULT_RETENTION_DAYS
from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.coordinator.store import default_db_path
from gridfleet.coordinator.window import DEFAULT_WINDOW, MAX_WINDOW, check_window
from gridfleet.energy import ChargingSpec
from gridfleet.errors import ConfigError, MapError, ScenarioError
from gridfleet.grid import GridMap
from gridfleet.heap import freeze_after_start
from gridfleet.maps import load_map
from gridfleet.metrics import add_metrics_arguments, metrics_options
from gridfleet.options import accounts_of, add_common, broker_url
from gridfleet.protocol import Charger, Place
from gridfleet.protocol.constants import DEFAULT_STEP_S
from gridfleet.scenario import Scenario, load_scenario
from gridfleet.shipped import is_name, shipped_file
from gridfleet.tasks import stop_on_signals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet coordinator`."""
    add_common(parser)
    parser.add_argument(
        "--map",
        required=True,
        metavar="FILE",
        help="Moving AI .map file, or a scenario .toml: its map, its [[chargers]], its [[places]] "
        "and its [charging] thresholds (its units and jobs are not the coordinator's: they come "
        "over MQTT)",
    )
    parser.add_argument(
        "--step",
        type=float,
        default=DEFAULT_STEP_S,
        metavar="S",
        help=f"step period in seconds (default {DEFAULT_STEP_S})",
    )
    parser.add_argument(
        "--db", default=None, metavar="PATH", help=f"job database (default {default_db_path()})"
    )
    parser.add_argument(
        "--window",
        type=int,
        default=DEFAULT_WINDOW,
        metavar="N",
        help=f"squares a unit may be released ahead on a free road, 1 to {MAX_WINDOW} "
        f"(default {DEFAULT_WINDOW}; 1: one square per order)",
    )
    parser.add_argument(
        "--client-id",
        default=None,
        help="MQTT client id and sender (default 'coordinator'; under another --root the client "
        "id names the root too, so fleets can share a broker)",
    )
    parser.add_argument(
        "--audit-days",
        type=float,
        default=DEFAULT_AUDIT_DAYS,
        metavar="DAYS",
        help=f"how long the audit trail keeps an entry (default {DEFAULT_AUDIT_DAYS:g} days)",
    )
    parser.add_argument(
        "--history-days",
        type=float,
        default=DEFAULT_RETENTION_DAYS,
        metavar="DAYS",
        help=f"how long the job history keeps an entry (default {DEFAULT_RETENTION_DAYS:g} days)",
    )
    parser.add_argument(
        "--vouched-senders",
        action="store_true",
        help="the broker drops a request or latch naming a client id its account does not own "
        "(gridfleet broker with --accounts does; Mosquitto does not): with --accounts, the "
        "audit marks the accounts it names verified",
    )
    energy = parser.add_argument_group(
        "energy (protocol.md §5.9; each flag overrides the scenario's [charging])"
    )
    for name, what in (
        ("critical", "at or below: no job, to a charger at once"),
        ("good", "below, and idle: to a charger"),
        ("sufficient", "a charging unit takes jobs again from here"),
        ("full", "a charging unit with nothing to do charges up to here"),
    ):
        energy.add_argument(
            f"--{name}-pct",
            type=float,
            default=None,
            metavar="PCT",
            help=f"{what} (default {getattr(ChargingSpec(), f'{name}_pct'):g})",
        )
    energy.add_argument(
        "--available-from",
        choices=("sufficient", "full"),
        default=None,
        help="from which threshold a charging unit takes jobs again (default sufficient)",
    )
    energy.add_argument(
        "--energy-policy",
        choices=POLICIES,
        default="gridfleet",
        help="gridfleet (default): the thresholds above with margins; naive: to the nearest "
        "charger only at critical, no check that a job can be finished, charged to full "
        "(a baseline to compare against)",
    )
    add_metrics_arguments(parser, "the coordinator")


def energy_settings(args: argparse.Namespace, charging: ChargingSpec) -> EnergySettings:
    """The thresholds: the scenario's [charging] (or the defaults), each flag given over it;
    ConfigError in one line when they cannot work."""

    def pick(name: str, own: float) -> float:
        given = getattr(args, f"{name}_pct")
        return own if given is None else float(given)

    spec = ChargingSpec(
        pick("critical", charging.critical_pct),
        pick("good", charging.good_pct),
        pick("sufficient", charging.sufficient_pct),
        pick("full", charging.full_pct),
        args.available_from or charging.available_from,
    )
    settings = EnergySettings.of(spec, args.energy_policy)
    problem = settings.problem()
    if problem is not None:
        raise ConfigError(f"charging thresholds: {problem}")
    return settings


@dataclass(frozen=True)
class Site:
    """What the coordinator takes from its --map: the map, its chargers, its named places and
    the charging thresholds."""

    grid: GridMap
    chargers: tuple[Charger, ...] = ()
    places: tuple[Place, ...] = ()
    charging: ChargingSpec = field(default_factory=ChargingSpec)


def load_site(path: str) -> Site:
    """A .map (no chargers, no places, default thresholds), or a scenario .toml's map, chargers,
    places and [charging]; a bare name is a shipped map, else a shipped scenario
    (`warehouse-energy`)."""
    if not path.endswith(".toml"):
        try:
            return Site(load_map(path))
        except MapError:
            if not is_name(path) or not shipped_file(path, ".toml").is_file():
                raise  # a file, or no shipped scenario of that name either: the map's error
    try:
        scenario = load_scenario(path)
    except ScenarioError as exc:
        raise ConfigError(str(exc)) from exc
    return site_of(scenario)


def site_of(scenario: Scenario) -> Site:
    """A loaded scenario's map, chargers, places and [charging], as the coordinator takes them."""
    chargers = tuple(Charger(name=c.name, square=c.square) for c in scenario.chargers)
    places = tuple(
        Place(name=p.name, square=p.square, kinds=list(p.kinds)) for p in scenario.places
    )
    return Site(scenario.grid, chargers, places, scenario.charging)


def run(args: argparse.Namespace) -> int:
    """Run until interrupted (SIGINT/SIGTERM)."""
    check_step(args.step)
    check_window(args.window)
    metrics = metrics_options(args)
    if not args.audit_days > 0:
        raise ConfigError(f"--audit-days {args.audit_days:g}: give more than 0 days")
    if not 0 < args.history_days < math.inf:
        raise ConfigError(f"--history-days {args.history_days:g}: give more than 0 days")
    identity = Identity(accounts_of(args), vouched=args.vouched_senders)
    site = load_site(args.map)
    energy = energy_settings(args, site.charging)
    coordinator = CoordinatorShell(
        broker_url(args, "coordinator"),
        site.grid,
        root=args.root,
        step_s=args.step,
        db_path=args.db,
        client_id=args.client_id,
        window=args.window,
        metrics=metrics,
        identity=identity,
        audit_days=args.audit_days,
        history_days=args.history_days,
        chargers=site.chargers,
        energy=energy,
        places=site.places,
    )

    async def main() -> None:
        freeze_after_start()
        await coordinator.run(stop_on_signals())

    asyncio.run(main())
    return 0
