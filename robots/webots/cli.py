"""`gridfleet webots-world`: write a Webots world for a scenario (robots/webots/README.md)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from gridfleet.accounts import load_accounts
from gridfleet.config import DEFAULT_MQTT_URL, check_step, parse_brokers, with_credentials
from gridfleet.errors import ConfigError
from gridfleet.protocol.constants import DEFAULT_ROOT, DEFAULT_STEP_S
from gridfleet.protocol.topics import Topics
from gridfleet.robots.webots.world_file import WEBOTS_VERSION, WorldOptions, world_text
from gridfleet.scenario import Scenario, load_scenario

PROTOS = Path(__file__).resolve().parent / "protos"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet webots-world`."""
    parser.add_argument("scenario", metavar="SCENARIO", help="scenario .toml file")
    parser.add_argument(
        "-o",
        "--out",
        required=True,
        type=Path,
        metavar="FILE.wbt",
        help="the world file to write (in robots/webots/worlds/, Webots finds the controller)",
    )
    parser.add_argument(
        "--units",
        metavar="ID,ID",
        help="run only these units (comma-separated); the others run elsewhere (another Webots, "
        "gridfleet robots --units) and this world shows them where their state says",
    )
    parser.add_argument(
        "--broker",
        metavar="URL[,URL...]",
        help="the broker every unit joins, or a comma-separated list of a cluster's nodes "
        "(default: none written; each unit then uses "
        f"$GRIDFLEET_BROKER, else {DEFAULT_MQTT_URL})",
    )
    parser.add_argument(
        "--accounts",
        metavar="FILE",
        help="accounts file ('gridfleet accounts init'): each unit logs in as itself; its "
        "password is then in the world file, which is written readable by you alone",
    )
    parser.add_argument(
        "--root",
        default=DEFAULT_ROOT,
        help=f"topic root, so fleets can share a broker (default {DEFAULT_ROOT!r})",
    )
    parser.add_argument(
        "--step",
        type=float,
        default=DEFAULT_STEP_S,
        metavar="SECONDS",
        help=f"the units' step period (default {DEFAULT_STEP_S}; the coordinator's --step)",
    )


def protos_from(folder: Path) -> str:
    """Where the PROTO files are, as a world in `folder` names them (relative when it can)."""
    try:
        return Path(os.path.relpath(PROTOS, folder.resolve())).as_posix()
    except ValueError:  # another drive (Windows): no relative path exists
        return PROTOS.as_posix()


def options(args: argparse.Namespace, scenario: Scenario) -> WorldOptions:
    """What the flags ask of the world; a bad flag raises ConfigError in one line."""
    units = None
    if args.units is not None:
        units = [u.strip() for u in args.units.split(",") if u.strip()]
        if not units:
            raise ConfigError("--units: give at least one unit id")
    Topics(args.root)
    broker = args.broker or ""
    if broker:
        parse_brokers(broker)
    return WorldOptions(
        protos=protos_from(args.out.parent),
        source=str(args.scenario),
        units=units,
        brokers=_brokers(args, scenario, broker, units),
        root=args.root,
        step_s=check_step(args.step),
    )


def _brokers(
    args: argparse.Namespace, scenario: Scenario, broker: str, units: list[str] | None
) -> dict[str, str]:
    """Each unit's broker URL: one broker; with accounts, a unit run here logs in as itself and
    a mirror as the dashboard (which may read every unit's state)."""
    if args.accounts is None:
        return {u.id: broker for u in scenario.units}
    accounts = load_accounts(args.accounts)
    url = broker or DEFAULT_MQTT_URL
    run_here = {u.id for u in scenario.units} if units is None else set(units)
    logins = {u.id: accounts.get(u.id if u.id in run_here else "dashboard") for u in scenario.units}
    return {uid: with_credentials(url, a.name, a.password) for uid, a in logins.items()}


def run(args: argparse.Namespace) -> int:
    """Write the world; bad input raises a GridfleetError with one clear line."""
    scenario = load_scenario(args.scenario)
    wanted = options(args, scenario)
    text = world_text(scenario, wanted)
    out: Path = args.out
    secret = args.accounts is not None
    try:
        fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if secret else 0o666)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        if secret:
            os.chmod(out, 0o600)  # an existing file keeps its mode through O_CREAT
    except OSError as exc:
        raise ConfigError(f"{out}: cannot write the world: {exc.strerror or exc}") from None
    run_here = len(scenario.units) if wanted.units is None else len(wanted.units)
    mirrors = len(scenario.units) - run_here
    shown = f", {mirrors} mirrored" if mirrors else ""
    print(
        f"wrote {out}: {scenario.name}, {run_here} grid unit(s){shown}; "
        f"open it in Webots {WEBOTS_VERSION}"
    )
    return 0
