"""`gridfleet up`: the whole system — broker, coordinator, units, dashboard — as supervised processes."""

from __future__ import annotations

import argparse
import asyncio
from collections.abc import Sequence
from pathlib import Path

from gridfleet.accounts import Accounts, load_accounts
from gridfleet.config import check_step, is_loopback, parse_brokers
from gridfleet.errors import ConfigError
from gridfleet.metrics import MetricsOptions
from gridfleet.options import add_common
from gridfleet.robots.shards import workers_for
from gridfleet.robots.vda5050.config import VehicleConfig, load_vehicles
from gridfleet.scenario import Scenario, load_scenario, with_units
from gridfleet.shipped import shipped_file
from gridfleet.system.assembly import LOOPBACK_OF, Assembly, SystemSpec
from gridfleet.system.supervisor import Supervisor, run_until_signal
from gridfleet.tasks import stop_on_signals
from gridfleet.tls import server_context

DEFAULT_SCENARIO = shipped_file("playfield", ".toml")  # the checkout's maps/, or the wheel's copy
MAKE_ACCOUNTS = "gridfleet accounts init --scenario FILE --out FILE"

EPILOG = """\
On loopback (the default) nothing needs setting up. To run on a LAN:
  gridfleet accounts init --scenario playfield --out fleet-accounts.toml
  gridfleet up --listen 0.0.0.0 --accounts fleet-accounts.toml
then open http://THIS-MACHINE:5000 and log in as 'operator' with its password from the file.
With TLS ('gridfleet accounts tls --out fleet-tls --host 127.0.0.1 --host THIS-MACHINE'):
  add --tls-cert fleet-tls/server.pem --tls-key fleet-tls/server.key --ca-file fleet-tls/ca.pem
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet up`."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument(
        "--scenario",
        type=Path,
        default=DEFAULT_SCENARIO,
        help="scenario file, or a shipped scenario by name (default playfield)",
    )
    parser.add_argument(
        "--step",
        type=float,
        default=0.5,
        help="step period in seconds for units and coordinator (default 0.5)",
    )
    parser.add_argument(
        "--demo", action="store_true", help="keep a stream of random feasible jobs coming"
    )
    add_common(parser, own_broker="the embedded broker, on --mqtt-port")
    parser.add_argument(
        "--listen",
        default="127.0.0.1",
        metavar="ADDR",
        help="address the embedded broker and the dashboard listen on (default 127.0.0.1: this "
        "machine only; 0.0.0.0: every network, which needs --accounts)",
    )
    parser.add_argument(
        "--accounts",
        type=Path,
        metavar="FILE",
        help=f"accounts file ({MAKE_ACCOUNTS!r}): the broker lets in only them, each component "
        "logs in as its own account, and people log in at the dashboard",
    )
    parser.add_argument(
        "--tls-cert",
        type=Path,
        metavar="FILE",
        help="the embedded broker's certificate ('gridfleet accounts tls'): mqtts:// and wss://; "
        "needs --tls-key and --ca-file",
    )
    parser.add_argument("--tls-key", type=Path, metavar="FILE", help="its private key")
    parser.add_argument(
        "--mqtt-port",
        type=int,
        default=1883,
        help="port of the embedded broker (default 1883; 0 picks a free one)",
    )
    parser.add_argument(
        "--ws-port",
        type=int,
        default=9001,
        help="websocket port of the embedded broker (default 9001; 0 free)",
    )
    parser.add_argument(
        "--broker-ws",
        metavar="URL",
        help="websocket URL of an external broker (with --broker), or a comma-separated list "
        "of a cluster's nodes",
    )
    parser.add_argument("--port", type=int, default=5000, help="dashboard port (default 5000)")
    parser.add_argument("--db", type=Path, help="coordinator job database (default: per user)")
    parser.add_argument(
        "--no-robots",
        action="store_true",
        help="start no simulated units: the scenario's units join from elsewhere (Webots, "
        "real robots: robots/webots/README.md)",
    )
    parser.add_argument(
        "--vehicles",
        type=Path,
        metavar="FILE",
        help="also run the VDA 5050 vehicles of this vehicles file as units (docs/vda5050.md)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="run the simulated units in N processes (default: one per 50 units, at most one "
        "per core)",
    )
    parser.add_argument(
        "--metrics",
        type=int,
        metavar="PORT",
        help="serve the coordinator's metrics in the Prometheus format on "
        "http://127.0.0.1:PORT/metrics (docs/monitoring.md)",
    )
    parser.add_argument(
        "--alerts",
        action="store_true",
        help="also run the alerts process: lost or stuck units, waiting jobs, the stop, a slow "
        "fleet, a coordinator down (docs/monitoring.md)",
    )
    parser.add_argument(
        "--alerts-config",
        type=Path,
        metavar="FILE",
        help="with --alerts: a TOML file whose [alerts] table sets its rules and webhook",
    )


def check_accounts(path: Path, scenario: Scenario) -> Accounts:
    """The accounts file, when it has an account for every component; else ConfigError."""
    accounts = load_accounts(path)
    for name, role in [("coordinator", "coordinator"), ("operator", "operator")] + [
        (u.id, "unit") for u in scenario.units
    ]:
        if name not in accounts.accounts:
            raise ConfigError(
                f"{path}: no account {name!r}, which 'up' needs: gridfleet accounts add {name} "
                f"--role {role} --file {path}"
            )
    return accounts


def check_adapter_account(
    accounts: Accounts, path: Path, vehicles_file: Path, vehicles: Sequence[VehicleConfig]
) -> None:
    """The VDA 5050 adapter's account speaks for every vehicle of the file, and the client id a
    vehicle of the file names is bound to that vehicle's account; else ConfigError."""
    made = f"gridfleet accounts add vda5050 --role vda5050 --vehicles {vehicles_file} --file {path}"
    adapter = accounts.accounts.get("vda5050")
    if adapter is None or adapter.role != "vda5050":
        raise ConfigError(f"{path}: no vda5050 account, which --vehicles needs: {made}")
    links = {(v.unit, v.topic) for v in adapter.vehicles}
    bound = accounts.bound_client_ids()
    for config in vehicles:
        v = config.vehicle
        if (v.unit, v.prefix) not in links:
            raise ConfigError(
                f"{path}: account vda5050 does not speak for vehicle {v.unit} of {vehicles_file}:"
                f' add {{ unit = "{v.unit}", topic = "{v.prefix}" }} to its vehicles'
            )
        binder = bound.get(config.client_id) if config.client_id is not None else None
        if config.client_id is not None and (
            binder is None or accounts.accounts[binder].unit != v.unit
        ):
            raise ConfigError(
                f"{path}: no vehicle account of unit {v.unit} binds its client_id "
                f"{config.client_id!r} ({vehicles_file}): add client_id = "
                f'"{config.client_id}" to that account\'s vehicles entry'
            )


def check_brokers(args: argparse.Namespace) -> None:
    """--broker and --broker-ws, a URL or a list each, are ones the parts can use; else one line."""
    if args.broker is not None:
        parse_brokers(args.broker)  # a bad, empty or repeated item, named
    if args.broker_ws is not None:
        for broker in parse_brokers(args.broker_ws):
            if not broker.websocket:
                raise ConfigError(
                    f"--broker-ws {broker}: the page needs a websocket URL, ws:// or wss://"
                )


def check_tls(args: argparse.Namespace) -> None:
    """--tls-cert, --tls-key and --ca-file go together, for the embedded broker; else ConfigError."""
    if args.tls_cert is None and args.tls_key is None:
        return
    if args.broker is not None:
        raise ConfigError(
            "--tls-cert is for the embedded broker; an external one is reached by its mqtts:// "
            "--broker URL and --ca-file"
        )
    if args.tls_cert is None or args.tls_key is None or args.ca_file is None:
        raise ConfigError(
            "TLS needs --tls-cert, --tls-key and --ca-file ('gridfleet accounts tls --out DIR' "
            "makes server.pem, server.key and ca.pem)"
        )
    server_context(args.tls_cert, args.tls_key)  # a bad file: one line now, not a dying broker


def spec_from(args: argparse.Namespace) -> SystemSpec:
    """What to run; every mistake raises ConfigError in one line before anything starts."""
    check_step(args.step)
    check_brokers(args)
    if not is_loopback(args.listen) and args.accounts is None:
        raise ConfigError(
            f"--listen {args.listen} lets anyone on that network drive the fleet: give "
            f"--accounts FILE (make it with '{MAKE_ACCOUNTS}'), or listen on 127.0.0.1"
        )
    check_tls(args)
    if args.metrics is not None:
        MetricsOptions(args.metrics)  # a bad port: one line now, not from the coordinator later
    alerts_config = check_alerts(args)
    scenario = with_units(load_scenario(args.scenario))
    workers = workers_for(len(scenario.units)) if args.workers is None else args.workers
    if workers < 1:
        raise ConfigError(f"--workers {args.workers}: give at least 1")
    vehicles = None
    if args.vehicles is not None:
        # A mistake in it: one line now, not from a child later.
        configs = load_vehicles(args.vehicles)
        vehicles = args.vehicles.resolve()
    accounts_file = None
    if args.accounts is not None:
        accounts = check_accounts(args.accounts, scenario)
        if args.vehicles is not None:
            check_adapter_account(accounts, args.accounts, args.vehicles, configs)
        accounts_file = args.accounts.resolve()  # the children may run elsewhere
    return SystemSpec(
        scenario=scenario,
        broker=args.broker,
        broker_ws=args.broker_ws,
        root=args.root,
        step_s=args.step,
        db_path=args.db,
        mqtt_port=args.mqtt_port,
        ws_port=args.ws_port,
        dashboard_port=args.port,
        accounts_file=accounts_file,
        listen=args.listen,
        tls_cert=args.tls_cert,
        tls_key=args.tls_key,
        ca_file=None if args.broker is not None or args.ca_file is None else Path(args.ca_file),
        feed=True,
        demo=args.demo,
        unit_workers=workers,
        robots=not args.no_robots,
        vehicles=vehicles,
        metrics_port=args.metrics,
        alerts=args.alerts,
        alerts_config=alerts_config,
    )


def check_alerts(args: argparse.Namespace) -> Path | None:
    """--alerts-config, checked now (a mistake: one line before anything starts), made absolute."""
    if args.alerts_config is not None and not args.alerts:
        raise ConfigError("--alerts-config is for --alerts")
    if not args.alerts:
        return None
    if args.accounts is not None and "alerts" not in load_accounts(args.accounts).accounts:
        raise ConfigError(
            f"{args.accounts}: no 'alerts' account for --alerts: add it with 'gridfleet accounts "
            f"add alerts --role alerts --file {args.accounts}'"
        )
    if args.alerts_config is None:
        return None
    from gridfleet.alerts.settings import load_settings  # only with --alerts

    load_settings(args.alerts_config)
    return Path(args.alerts_config).resolve()


async def bring_up(args: argparse.Namespace, supervisor: Supervisor) -> str:
    """Start every component in order, as processes; returns what to open, in words."""
    spec = spec_from(args)  # checked here, not by each component once the broker is up
    system = await Assembly(spec, "processes", supervisor).start_processes()
    assert system.dashboard_url is not None
    return where_to_open(system.dashboard_url, spec.listen, spec.accounts_file is not None)


def where_to_open(url: str, listen: str, login: bool) -> str:
    """The dashboard's address for a person: on every address, here and from elsewhere."""
    said = url
    here = LOOPBACK_OF.get(listen)
    if here is not None:
        local = url.replace(f"//{listen}:", f"//{here}:", 1)
        said = f"{local} (from other machines: {url.replace(listen, 'THIS-MACHINE', 1)})"
    return f"{said}, log in as operator" if login else said


async def _main(args: argparse.Namespace) -> int:
    supervisor = Supervisor()
    try:
        where = await bring_up(args, supervisor)
    except BaseException:
        await supervisor.stop()
        raise
    stop = stop_on_signals()  # before saying so: a signal right after the line must stop us
    supervisor.say("up", f"gridfleet is running: open {where} (Ctrl-C stops everything)")
    return await run_until_signal(supervisor, stop)


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet up`."""
    return asyncio.run(_main(args))
