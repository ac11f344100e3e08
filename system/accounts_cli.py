"""`gridfleet accounts`: make the broker accounts file for a fleet, and add accounts to it; make
the broker's TLS certificate."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import get_args

from gridfleet.accounts import (
    TOKEN_ROLES_TEXT,
    Account,
    Accounts,
    Role,
    VehicleLink,
    default_accounts,
    load_accounts,
    new_password,
    write_accounts,
)
from gridfleet.api_tokens import created_text, issue_token, revoke_tokens
from gridfleet.broker.aedes import launcher_command, write_accounts_json
from gridfleet.broker.certs import DEFAULT_HOSTS, make_tls, write_tls
from gridfleet.broker.mosquitto import (
    MOSQUITTO_USER,
    RunAs,
    blocked,
    bridge_conf,
    hand_over,
    mosquitto_conf,
    runs_as,
    write_conf,
    write_files,
)
from gridfleet.broker.rabbitmq import CONF_FILE as RABBITMQ_CONF_FILE
from gridfleet.broker.rabbitmq import VHOST as RABBITMQ_VHOST
from gridfleet.broker.rabbitmq import rabbitmq_conf
from gridfleet.broker.rabbitmq import write_definitions as write_rabbitmq_definitions
from gridfleet.errors import ConfigError
from gridfleet.protocol import Topics
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.robots.vda5050.config import load_vehicles
from gridfleet.scenario import load_scenario, with_units


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Subcommands of `gridfleet accounts`."""
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    init = sub.add_parser("init", help="write the accounts a scenario's fleet needs")
    init.add_argument(
        "--scenario",
        type=Path,
        required=True,
        help="scenario file (TOML), or a shipped scenario by name (playfield)",
    )
    init.add_argument("--out", type=Path, required=True, help="accounts file to write (mode 600)")
    init.add_argument("--force", action="store_true", help="replace an existing file")
    init.add_argument(
        "--vehicles",
        type=Path,
        metavar="FILE",
        help="also the VDA 5050 adapter's account and one per vehicle of this vehicles file",
    )
    add = sub.add_parser("add", help="add one account (a new unit, its device, a person)")
    add.add_argument("name", help="account name: the MQTT username (and, for a unit, its id)")
    add.add_argument("--role", required=True, choices=get_args(Role))
    add.add_argument("--unit", help="the unit a unit or device account belongs to")
    add.add_argument("--file", type=Path, required=True, help="accounts file to add to")
    add.add_argument(
        "--vehicles",
        type=Path,
        metavar="FILE",
        help="vehicle and vda5050 roles: the vehicles file naming the vehicles' topics",
    )
    token = sub.add_parser(
        "token",
        help="make an API token for an account (printed once), list or revoke its tokens",
        description="A new token for the dashboard's HTTP API (printed once, kept hashed in the "
        f"file), for {TOKEN_ROLES_TEXT} accounts; --list shows the account's token ids, "
        "--revoke takes one (or all) away: the dashboard refuses it at its next request.",
    )
    token.add_argument("name", help="the account the token acts as")
    token.add_argument("--file", type=Path, required=True, help="accounts file")
    what = token.add_mutually_exclusive_group()
    what.add_argument(
        "--revoke", metavar="ID", help="take token ID (8 hex digits, from --list) away, or 'all'"
    )
    what.add_argument("--list", action="store_true", help="the account's token ids and dates")
    mosq = sub.add_parser(
        "mosquitto", help="write Mosquitto's password, ACL and config files from them"
    )
    mosq.add_argument("--file", type=Path, required=True, help="accounts file")
    mosq.add_argument(
        "--out", type=Path, required=True, help="directory for passwd, acl and mosquitto.conf"
    )
    mosq.add_argument("--root", default=DEFAULT_ROOT, help=f"topic root (default {DEFAULT_ROOT!r})")
    mosq.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)"
    )
    mosq.add_argument("--port", type=int, default=1883, help="MQTT port (default 1883)")
    mosq.add_argument("--ws-port", type=int, default=9001, help="websocket port (default 9001)")
    mosq.add_argument("--no-ws", action="store_true", help="no websocket listener")
    mosq.add_argument("--tls-cert", type=Path, help="server certificate ('accounts tls')")
    mosq.add_argument("--tls-key", type=Path, help="its private key")
    mosq.add_argument(
        "--persistence",
        type=Path,
        help="where Mosquitto keeps retained messages (the latched stop among them) across "
        "restarts (default OUT/data; 'none': nothing survives a restart)",
    )
    mosq.add_argument(
        "--bridge-to",
        metavar="HOST:PORT",
        help="a hall's broker: bridge it to the central broker at HOST:PORT (units and devices "
        "here, coordinator and people there; docs/brokers.md)",
    )
    mosq.add_argument(
        "--bridge-account",
        metavar="NAME",
        help="with --bridge-to: the bridge account it logs in as there ('accounts add NAME "
        "--role bridge')",
    )
    mosq.add_argument(
        "--bridge-ca",
        type=Path,
        metavar="FILE",
        help="with --bridge-to: the bridge speaks TLS to the central broker, trusting this CA "
        "('accounts tls' wrote it as ca.pem; HOST must be a name or address its certificate has)",
    )
    aedes = sub.add_parser(
        "aedes", help="write the accounts file of the aedes cluster's launcher from them"
    )
    aedes.add_argument("out", type=Path, metavar="DIR", help="directory for aedes-accounts.json")
    aedes.add_argument("--file", type=Path, required=True, help="accounts file")
    aedes.add_argument(
        "--root", default=DEFAULT_ROOT, help=f"topic root (default {DEFAULT_ROOT!r})"
    )
    rabbit = sub.add_parser(
        "rabbitmq", help="write RabbitMQ's definitions (users, topic permissions) and config"
    )
    rabbit.add_argument(
        "out", type=Path, metavar="DIR", help="directory for definitions.json and rabbitmq.conf"
    )
    rabbit.add_argument("--file", type=Path, required=True, help="accounts file")
    rabbit.add_argument(
        "--root", default=DEFAULT_ROOT, help=f"topic root (default {DEFAULT_ROOT!r})"
    )
    rabbit.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)"
    )
    rabbit.add_argument("--port", type=int, default=1883, help="MQTT port (default 1883)")
    rabbit.add_argument(
        "--ws-port", type=int, default=15675, help="websocket port, path /ws (default 15675)"
    )
    rabbit.add_argument("--no-ws", action="store_true", help="no websocket listener")
    tls = sub.add_parser("tls", help="make a local CA and the broker's TLS certificate")
    tls.add_argument("--out", type=Path, required=True, help="directory for the three files")
    tls.add_argument(
        "--host",
        action="append",
        metavar="NAME_OR_IP",
        help="an address or name clients connect to; repeat for each (default "
        f"{' and '.join(DEFAULT_HOSTS)}; on a LAN give its address too)",
    )
    tls.add_argument("--force", action="store_true", help="replace existing files (a new CA)")


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet accounts`."""
    if args.action == "init":
        if args.out.exists() and not args.force:
            raise ConfigError(f"{args.out} exists; --force replaces it (and every password)")
        scenario = with_units(load_scenario(args.scenario))
        links = _links(args.vehicles) if args.vehicles is not None else ()
        accounts = default_accounts([u.id for u in scenario.units], links)
        write_accounts(accounts, args.out)
        print(f"wrote {len(accounts.accounts)} accounts to {args.out} (keep it private)")
        return 0
    if args.action == "tls":
        hosts = args.host or list(DEFAULT_HOSTS)
        ca, cert, key = write_tls(make_tls(hosts), args.out, force=args.force)
        print(
            f"wrote {ca} (give it to clients: --ca-file {ca}), {cert} and {key} (keep it "
            f"private) for {', '.join(hosts)}; run 'gridfleet broker --tls-cert {cert} "
            f"--tls-key {key}'"
        )
        return 0
    if args.action == "mosquitto":
        return _mosquitto(args)
    if args.action == "aedes":
        return _aedes(args)
    if args.action == "rabbitmq":
        return _rabbitmq(args)
    if args.action == "token":
        return _token(args)
    # A unit's or a vehicle's account is named after its unit unless --unit says otherwise.
    named = args.name if args.role in ("unit", "vehicle") else None
    unit = args.unit if args.unit is not None else named
    accounts = load_accounts(args.file)
    links = _vehicles_of(args.role, unit, args.vehicles)
    account = Account(args.name, new_password(), args.role, unit, links)
    accounts = accounts.with_account(account)
    write_accounts(accounts, args.file)
    print(f"added {args.role} account {args.name} to {args.file}")
    return 0


def _token(args: argparse.Namespace) -> int:
    """`gridfleet accounts token`: a new token (its text alone on stdout), --list, --revoke."""
    accounts = load_accounts(args.file)
    name = args.name
    if args.list:
        tokens = accounts.get(name).tokens
        for t in tokens:
            print(f"{t.id}  {created_text(t.created)}")
        if not tokens:
            print(f"account {name} holds no API tokens", file=sys.stderr)
        return 0
    if args.revoke is not None:
        gone, accounts = revoke_tokens(accounts, name, args.revoke)
        if gone:
            write_accounts(accounts, args.file)
        for t in gone:
            print(f"revoked API token {t.id} of {name}")
        if not gone:
            print(f"account {name} holds no API tokens: nothing revoked", file=sys.stderr)
        return 0
    text, record, accounts = issue_token(accounts, name)
    write_accounts(accounts, args.file)
    print(text)
    print(
        f"new API token {record.id} of {name} ({accounts.get(name).role}), shown this once: "
        "the file keeps only its hash. Send it as 'Authorization: Bearer TOKEN'; revoke it with "
        f"'gridfleet accounts token {name} --file {args.file} --revoke {record.id}'",
        file=sys.stderr,
    )
    return 0


def _links(path: Path) -> tuple[VehicleLink, ...]:
    """Every vehicle of a vehicles file, as accounts name them."""
    return tuple(
        VehicleLink(c.vehicle.unit, c.vehicle.prefix, c.client_id) for c in load_vehicles(path)
    )


def _vehicles_of(role: str, unit: str | None, path: Path | None) -> tuple[VehicleLink, ...]:
    """The vehicles a new account of `role` speaks for: all of the file's, or `unit`'s."""
    if role not in ("vehicle", "vda5050"):
        if path is not None:
            raise ConfigError(f"--vehicles is for the vehicle and vda5050 roles, not {role}")
        return ()
    if path is None:
        raise ConfigError(f"a {role} account needs --vehicles FILE (the vehicles' topics)")
    links = _links(path)
    if role == "vda5050":
        return links
    mine = tuple(v for v in links if v.unit == unit)
    if not mine:
        raise ConfigError(f"{path}: no vehicle of unit {unit!r}")
    return mine


def _aedes(args: argparse.Namespace) -> int:
    """`gridfleet accounts aedes DIR`: the launcher's accounts file (mode 600), and how to run a
    cluster instance with it."""
    accounts = load_accounts(args.file)
    written = write_accounts_json(accounts, Topics(args.root), args.out.resolve())
    command = " ".join(launcher_command(written, instance_id="aedes-0"))
    print(
        f"wrote {written} ({len(accounts.accounts)} accounts, password hashes only; keep it "
        f"private): run each instance on the same Redis, e.g. '{command}' (docs/brokers.md)"
    )
    return 0


def _rabbitmq(args: argparse.Namespace) -> int:
    """`gridfleet accounts rabbitmq DIR`: definitions.json (mode 600) and a rabbitmq.conf that
    loads it, and how to run a node with them."""
    accounts = load_accounts(args.file)
    out = args.out.resolve()
    definitions = write_rabbitmq_definitions(accounts, Topics(args.root), out)
    conf = out / RABBITMQ_CONF_FILE
    conf.write_text(
        rabbitmq_conf(
            host=args.host,
            port=args.port,
            ws_port=None if args.no_ws else args.ws_port,
            definitions=definitions,
        ),
        encoding="utf-8",
    )
    print(
        f"wrote {definitions} ({len(accounts.accounts)} accounts, password hashes only; keep it "
        f"private) and {conf} (mqtt.allow_anonymous false, vhost {RABBITMQ_VHOST}): enable "
        "the plugins ('rabbitmq-plugins enable rabbitmq_mqtt rabbitmq_web_mqtt') and run each "
        f"node with RABBITMQ_CONFIG_FILE={conf}; the definitions load at its boot "
        f"('rabbitmqctl import_definitions {definitions}' loads them into a running cluster; "
        "docs/brokers.md)"
    )
    return 0


def _mosquitto(args: argparse.Namespace) -> int:
    """`gridfleet accounts mosquitto`: passwd, acl and a mosquitto.conf that uses them, owned by
    the user Mosquitto runs as (user mosquitto when this runs as root)."""
    if (args.tls_cert is None) != (args.tls_key is None):
        raise ConfigError("TLS needs both --tls-cert FILE and --tls-key FILE")
    for flag, given in (("--tls-cert", args.tls_cert), ("--tls-key", args.tls_key)):
        if given is not None and not given.is_file():
            raise ConfigError(
                f"{flag} {given}: no such file ('accounts tls' writes server.pem and server.key)"
            )
    accounts = load_accounts(args.file)
    bridge = _bridge(
        accounts, args.bridge_to, args.bridge_account, Topics(args.root), args.bridge_ca
    )
    out = args.out.resolve()
    persistence = args.persistence if args.persistence is not None else out / "data"
    keep = None if str(persistence) == "none" else persistence.resolve()
    if keep is not None and out.is_relative_to(keep):
        # Mosquitto's user may write there: it could put a mosquitto.conf of its own, read as root.
        raise ConfigError(
            f"--persistence {persistence}: it holds mosquitto.conf; give Mosquitto's data a "
            "folder of its own (default OUT/data)"
        )
    owner = runs_as()
    passwd, acl = write_files(accounts, Topics(args.root), out, owner)
    # Mosquitto writes mosquitto.db.new there and renames it: its own folder. One this command
    # makes (the default OUT/data above all) becomes the owner's; one that was there
    # (/var/lib/mosquitto, say) is left as it is, and checked below.
    if keep is not None and (keep == out / "data" or not keep.exists()):
        keep.mkdir(parents=True, exist_ok=True)
        keep.chmod(0o700)
        hand_over(keep, owner)
    conf = out / "mosquitto.conf"
    write_conf(
        conf,
        mosquitto_conf(
            passwd,
            acl,
            host=args.host,
            port=args.port,
            ws_port=None if args.no_ws else args.ws_port,
            tls_cert=None if args.tls_cert is None else args.tls_cert.resolve(),
            tls_key=None if args.tls_key is None else args.tls_key.resolve(),
            persistence_dir=keep,
            user=None if owner is None else owner.name,
        )
        + bridge,
        owner,
    )
    ran = f"wrote {passwd}, {acl} and {conf} (allow_anonymous false): run 'mosquitto -c {conf}'"
    if owner is None:
        print(ran)
        if os.geteuid() == 0:
            print(
                f"note: there is no user {MOSQUITTO_USER} here, whom Mosquitto started as root "
                "runs as, and passwd and acl are root's only: install Mosquitto's package (it "
                "makes the user) and run this again",
                file=sys.stderr,
            )
    else:
        name, kept = owner.name, "" if keep is None else f" and {keep}"
        how = (
            f"as {name}, or as root: it drops" if owner.uid == os.geteuid() else "as root: it drops"
        )
        print(
            f"{ran} ({how} to {name}, 'user {name}' in it); user {name} owns passwd, acl{kept}, "
            "and none but it may read them"
        )
        for line in _unusable(owner, passwd, acl, keep, args):
            print(f"note: user {name}, whom Mosquitto runs as, {line}", file=sys.stderr)
    bound = sorted(accounts.bound_client_ids())
    if bound:
        print(
            f"note: Mosquitto cannot bind client ids to accounts: the client_id of "
            f"{', '.join(bound)} is not enforced there, and any account can take over any "
            "client's id (docs/brokers.md, 'Client ids on Mosquitto')",
            file=sys.stderr,
        )
    return 0


def _unusable(
    owner: RunAs, passwd: Path, acl: Path, keep: Path | None, args: argparse.Namespace
) -> list[str]:
    """What Mosquitto, running as `owner`, could not open of what it is given: a line for each
    cause, with its fix; none when it can open it all."""
    given = [passwd, acl, *(p for p in (args.tls_cert, args.tls_key, args.bridge_ca) if p)]
    found = [(p, blocked(owner, p)) for p in given]
    if keep is not None:
        found.append((keep, blocked(owner, keep, write=True)))
    causes: dict[str, list[Path]] = {}
    for path, why in found:
        if why is not None:
            causes.setdefault(why, []).append(path.resolve())
    lines = []
    for why, paths in causes.items():
        if why.startswith("cannot enter"):
            names = ", ".join(p.name for p in paths)
            fix = "put them where it can enter every folder (--out /etc/mosquitto/gridfleet, say)"
            lines.append(f"{why}, so it cannot open {names}: {fix}")
        elif paths[0].stat().st_uid == owner.uid:
            lines.append(f"{why}: chmod u+{'rwx' if paths[0] == keep else 'r'} {paths[0]}")
        else:
            lines.append(f"{why}: chown {owner.name}: {paths[0]}")
    return lines


def _bridge(
    accounts: Accounts, to: str | None, name: str | None, topics: Topics, ca: Path | None
) -> str:
    """The bridge section `--bridge-to`, `--bridge-account` (and `--bridge-ca`) ask for ('' without
    them)."""
    if to is None and name is None:
        if ca is not None:
            raise ConfigError("--bridge-ca is for a bridge: give --bridge-to and --bridge-account")
        return ""
    if to is None or name is None:
        raise ConfigError("a bridge needs both --bridge-to HOST:PORT and --bridge-account NAME")
    host, colon, port = to.rpartition(":")
    if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"--bridge-to {to!r}: give the central broker as HOST:PORT")
    account = accounts.get(name)
    if account.role != "bridge":
        raise ConfigError(
            f"--bridge-account {name}: a {account.role} account; make one with "
            f"'gridfleet accounts add {name} --role bridge --file FILE'"
        )
    if ca is not None and not ca.is_file():
        raise ConfigError(f"--bridge-ca {ca}: no such file (the CA 'accounts tls' wrote: ca.pem)")
    return bridge_conf(account, host, int(port), topics, None if ca is None else ca.resolve())
