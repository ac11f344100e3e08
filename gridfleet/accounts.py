"""Broker accounts: who may connect, in which role, and what each role may publish and read.

An accounts file is TOML, readable by its owner only, one table per account:

    [accounts.unit1]
    password = "…"
    role = "unit"
    unit = "unit1"

    [accounts.agv1]             # a VDA 5050 vehicle: its own topics only (docs/vda5050.md)
    password = "…"
    role = "vehicle"
    unit = "agv1"
    vehicles = [{ unit = "agv1", topic = "uagv/v2/acme/sn-7", client_id = "acme-sn-7" }]

    [accounts.vda5050]          # the adapter: the vehicles' orders, and their units' topics
    password = "…"
    role = "vda5050"
    vehicles = [{ unit = "agv1", topic = "uagv/v2/acme/sn-7" }]

    [accounts.ann]              # a person; her scripts' API tokens (gridfleet/api_tokens.py)
    password = "…"
    role = "operator"
    tokens = [{ id = "3f9c01ab", sha256 = "…", created = "2026-12-02T07:40:00Z" }]

The broker hashes the passwords it checks; clients read theirs from this file (`--accounts FILE
--account NAME`). A vehicle's `client_id` (optional, from the vehicles file) is bound to its vehicle
account: the embedded broker lets no other account use it. `rules()` derives each account's topic rules from the protocol's topic table, so
an ACL never drifts from protocol.md.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import stat
import tempfile
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, get_args

from pydantic import BaseModel, ConfigDict, ValidationError
from pydantic_core import ErrorDetails

from gridfleet.api_tokens import TokenRecord, created_text, parse_created
from gridfleet.config import CLIENT_ID, owner_of
from gridfleet.errors import ConfigError, ProtocolError
from gridfleet.protocol import TOPICS, Topics, validate_id
from gridfleet.protocol.constants import REMOVED_UNIT_KINDS
from gridfleet.textfile import read_text

Role = Literal[
    "coordinator",
    "unit",
    "device",
    "dashboard",
    "operator",
    "vehicle",
    "vda5050",
    "bridge",
    "alerts",  # the alerts process (`gridfleet alerts`): its view and its answers to acks
    "viewer",  # a person who may read the fleet but not change it (nor acknowledge alerts)
]
ROLES: tuple[Role, ...] = get_args(Role)
# The roles that may hold API tokens (the dashboard's HTTP API, gridfleet/api_tokens.py): people
# and the dashboard's own; viewers read through it, the others change.
TOKEN_ROLES: tuple[Role, ...] = ("operator", "dashboard", "viewer")
TOKEN_ROLES_TEXT = f"{', '.join(TOKEN_ROLES[:-1])} and {TOKEN_ROLES[-1]}"
REQUEST_KINDS = (
    "submit_job",
    "cancel_job",
    "set_goal",
    "control_unit",
    "clear_obstacles",
    "remove_unit",  # a lost unit off the floor for good (protocol.md §6.11)
    "close_zone",  # close a rectangle of squares (protocol.md §5.11)
    "open_zone",
    "ack_alert",  # answered by the alerts process, not the coordinator
    "audit",  # a page of the audit trail (protocol.md §6.8): people, not viewers
    "job_history",  # a page of the job history (protocol.md §6.10)
)
# The dashboard's own report of a login, logout or failed login, for the audit (§6.9): only a
# dashboard account may publish it, not an operator's.
DASHBOARD_REQUEST_KINDS = ("audit_login",)
MIN_PASSWORD = 12
# A VDA 5050 vehicle's topics: interfaceName/majorVersion/manufacturer/serialNumber/<topic>.
# Each level one of MQTT's, printable, without spaces (a Mosquitto ACL line ends at the topic).
_LEVEL = r"[^/+#\s\x00-\x1f\x7f]+"
VDA_TOPIC = re.compile(rf"(?!\$){_LEVEL}/v[0-9]+/{_LEVEL}/{_LEVEL}")
# What a unit publishes of itself (the adapter, for a vehicle's unit, its `vehicle` too).
UNIT_OWN_KINDS = ("connection", "factsheet", "state", "direction", "stop")
VDA_FROM_VEHICLE = ("state", "connection", "factsheet", "visualization")
VDA_TO_VEHICLE = ("order", "instantActions")


@dataclass(frozen=True)
class VehicleLink:
    """A VDA 5050 vehicle an account speaks for: its gridfleet unit, its topics' prefix and,
    if its vehicles file names one, the MQTT client id bound to its vehicle account."""

    unit: str
    topic: str  # interfaceName/majorVersion/manufacturer/serialNumber
    client_id: str | None = None

    def __post_init__(self) -> None:
        validate_id(self.unit, "vehicle unit")
        if not VDA_TOPIC.fullmatch(self.topic):
            raise ConfigError(
                f"vehicle {self.unit}: topic {self.topic!r} is not "
                "interfaceName/vN/manufacturer/serialNumber"
            )
        if self.client_id is not None and not CLIENT_ID.fullmatch(self.client_id):
            raise ConfigError(
                f"vehicle {self.unit}: client_id {self.client_id!r} is not 1-64 printable "
                "ASCII characters without spaces"
            )


@dataclass(frozen=True)
class Account:
    """One broker account: its name (the MQTT username), password, role and, for units and
    devices, the unit it belongs to; for people, the API tokens they hold."""

    name: str
    password: str
    role: Role
    unit: str | None = None
    vehicles: tuple[VehicleLink, ...] = ()
    tokens: tuple[TokenRecord, ...] = ()

    def __post_init__(self) -> None:
        validate_id(self.name, "account name")
        if self.role not in ROLES:
            raise ConfigError(f"account {self.name}: role {self.role!r} is not one of {ROLES}")
        if len(self.password) < MIN_PASSWORD:
            raise ConfigError(
                f"account {self.name}: the password must have at least {MIN_PASSWORD} characters"
            )
        needs_unit = self.role in ("unit", "device", "vehicle")
        if needs_unit and self.unit is None:
            raise ConfigError(f"account {self.name}: a {self.role} account names its unit")
        if not needs_unit and self.unit is not None:
            raise ConfigError(f"account {self.name}: a {self.role} account has no unit")
        if self.unit is not None:
            validate_id(self.unit, f"account {self.name}: unit")
        self._check_vehicles()
        if self.tokens and self.role not in TOKEN_ROLES:
            raise ConfigError(
                f"account {self.name}: a {self.role} account holds no API tokens (only "
                f"{TOKEN_ROLES_TEXT} accounts do)"
            )
        twice = _repeated([t.id for t in self.tokens])
        if twice is not None:
            raise ConfigError(f"account {self.name}: API token id {twice!r} twice")

    def _check_vehicles(self) -> None:
        links = self.vehicles
        if self.role == "vehicle" and [v.unit for v in links] != [self.unit]:
            raise ConfigError(
                f"account {self.name}: a vehicle account names one vehicle, of its unit {self.unit}"
            )
        if self.role == "vda5050" and not links:
            raise ConfigError(f"account {self.name}: a vda5050 account names its vehicles")
        if self.role not in ("vehicle", "vda5050") and links:
            raise ConfigError(f"account {self.name}: a {self.role} account has no vehicles")
        for what in ("unit", "topic", "client_id"):
            twice = _repeated([getattr(v, what) for v in links if getattr(v, what) is not None])
            if twice is not None:
                raise ConfigError(f"account {self.name}: vehicle {what} {twice!r} twice")


def _repeated(values: Sequence[str]) -> str | None:
    """The first (in sorted order) of `values` that occurs more than once, if any."""
    return min((x for x in set(values) if values.count(x) > 1), default=None)


@dataclass(frozen=True)
class Accounts:
    """Every account, by name."""

    accounts: dict[str, Account] = field(default_factory=dict)
    # Each API token id: the account holding it, and its record (made from `accounts`).
    _tokens_by_id: dict[str, tuple[Account, TokenRecord]] = field(
        init=False, repr=False, compare=False, default_factory=dict
    )

    def __post_init__(self) -> None:
        self.bound_client_ids()  # ConfigError when two accounts would own one client id
        object.__setattr__(self, "_tokens_by_id", self._index_tokens())

    def _index_tokens(self) -> dict[str, tuple[Account, TokenRecord]]:
        """Each API token id, with the account holding it and its record; ConfigError when two
        accounts hold one id."""
        held: dict[str, tuple[Account, TokenRecord]] = {}
        for account in self.accounts.values():
            for token in account.tokens:
                other = held.get(token.id)
                if other is not None:
                    raise ConfigError(
                        f"accounts {other[0].name} and {account.name} both hold API token id "
                        f"{token.id!r}"
                    )
                held[token.id] = (account, token)
        return held

    def token_holder(self, token_id: str) -> tuple[Account, TokenRecord] | None:
        """The account holding API token `token_id`, and its record (None: nobody)."""
        return self._tokens_by_id.get(token_id)

    def bound_client_ids(self) -> dict[str, str]:
        """Each client id a vehicle account's `client_id` binds, and that account's name.

        ConfigError when two vehicle accounts bind one, or when it is an id another account's
        name owns (`coordinator`, `unit1-x`): a client id has one owner.
        """
        bound: dict[str, str] = {}
        for account in self.accounts.values():
            if account.role != "vehicle":
                continue
            for v in account.vehicles:
                if v.client_id is None:
                    continue
                if v.client_id in bound:
                    raise ConfigError(
                        f"accounts {bound[v.client_id]} and {account.name} both bind client id "
                        f"{v.client_id!r}"
                    )
                owner = owner_of(v.client_id, self.accounts)
                if owner is not None and owner != account.name:
                    raise ConfigError(
                        f"account {account.name}: client id {v.client_id!r} is account "
                        f"{owner!r}'s (its name)"
                    )
                bound[v.client_id] = account.name
        return bound

    def get(self, name: str) -> Account:
        """The account called `name`; ConfigError naming the known ones when there is none."""
        try:
            return self.accounts[name]
        except KeyError:
            known = ", ".join(sorted(self.accounts)) or "none"
            raise ConfigError(f"no account {name!r} (known: {known})") from None

    def with_account(self, account: Account) -> Accounts:
        """These accounts and `account`; ConfigError when its name is taken."""
        if account.name in self.accounts:
            raise ConfigError(f"account {account.name!r} exists already")
        return Accounts({**self.accounts, account.name: account})

    def with_replaced(self, account: Account) -> Accounts:
        """These accounts with `account` instead of the one of its name; ConfigError naming the
        known ones when there is none."""
        self.get(account.name)
        return Accounts({**self.accounts, account.name: account})

    def units(self) -> set[str]:
        """The units that have a unit account."""
        return {a.unit for a in self.accounts.values() if a.role == "unit" and a.unit}


def new_password() -> str:
    """A random password (24 URL-safe characters, 144 bits)."""
    return secrets.token_urlsafe(18)


def default_accounts(units: list[str], vehicles: Sequence[VehicleLink] = ()) -> Accounts:
    """The accounts a fleet of `units` needs: coordinator, dashboard, operator, and a unit and a
    device account per unit (`<unit>` and `device-<unit>`), each with a random password; with
    VDA 5050 `vehicles`, the adapter's account (`vda5050`) and one per vehicle (`<unit>`)."""
    made = [
        Account("coordinator", new_password(), "coordinator"),
        Account("dashboard", new_password(), "dashboard"),
        Account("operator", new_password(), "operator"),
        Account("alerts", new_password(), "alerts"),
    ]
    for unit in units:
        made.append(Account(unit, new_password(), "unit", unit))
        made.append(Account(f"device-{unit}", new_password(), "device", unit))
    if vehicles:
        made.append(Account("vda5050", new_password(), "vda5050", vehicles=tuple(vehicles)))
    for v in vehicles:
        made.append(Account(v.unit, new_password(), "vehicle", v.unit, (v,)))
    twice = _repeated([a.name for a in made])
    if twice is not None:
        raise ConfigError(f"account {twice!r} twice: a unit and a vehicle share the id")
    return Accounts({a.name: a for a in made})


class _VehicleTable(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    unit: str
    topic: str
    client_id: str | None = None


class _TokenTable(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    id: str
    sha256: str
    created: str


class _AccountTable(BaseModel):
    """One [accounts.NAME] table: strings (checked by Account), vehicles and tokens, no other
    key."""

    model_config = ConfigDict(extra="forbid", strict=True)

    password: str | None = None
    role: Role | None = None
    unit: str | None = None
    vehicles: list[_VehicleTable] = []
    tokens: list[_TokenTable] = []


class _AccountsFile(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    accounts: dict[str, _AccountTable] = {}


def _shape_problem(error: ErrorDetails) -> str:
    """The first thing wrong with the file's shape, in one line."""
    loc = error["loc"]
    if len(loc) == 1:
        if error["type"] == "extra_forbidden":
            return f"unknown table {loc[0]!r} (only [accounts.NAME])"
        return "no [accounts.NAME] tables"
    name = loc[1]
    if len(loc) == 2:
        return f"accounts.{name} must be a table"
    if error["type"] == "extra_forbidden" and len(loc) == 3:
        return f"accounts.{name}: unknown key {loc[2]!r}"
    if error["type"] == "literal_error":
        return f"account {name}: role {error['input']!r} is not one of {ROLES}"
    if loc[2] == "vehicles":
        return (
            f'accounts.{name}: vehicles is a list of {{ unit = "…", topic = "…" }}'
            ' (and optionally client_id = "…")'
        )
    if loc[2] == "tokens":
        return (
            f'accounts.{name}: tokens is a list of {{ id = "…", sha256 = "…", created = "…" }}, '
            "strings ('gridfleet accounts token' writes them)"
        )
    return f"accounts.{name}: password, role and unit are strings"


def load_accounts(path: str | Path) -> Accounts:
    """Read an accounts file; ConfigError naming the file and the problem."""
    p = Path(path)
    text = read_text(p, "accounts file", ConfigError)
    if os.name == "posix" and p.stat().st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(f"{p}: others can read it; make it private (chmod 600 {p})")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: cannot read the accounts file: {exc}") from None
    try:
        shape = _AccountsFile.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{p}: {_shape_problem(exc.errors()[0])}") from None
    if not shape.accounts:
        raise ConfigError(f"{p}: no [accounts.NAME] tables")
    accounts: dict[str, Account] = {}
    for name, entry in shape.accounts.items():
        if entry.password is None or entry.role is None:
            raise ConfigError(f"{p}: accounts.{name}: needs a password and a role")
        try:
            links = tuple(VehicleLink(v.unit, v.topic, v.client_id) for v in entry.vehicles)
            tokens = _token_records(name, entry.tokens)
            accounts[name] = Account(name, entry.password, entry.role, entry.unit, links, tokens)
        except (ConfigError, ProtocolError) as exc:
            raise ConfigError(f"{p}: {exc}") from None
    try:
        return Accounts(accounts)
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from None


def _token_records(name: str, tables: list[_TokenTable]) -> tuple[TokenRecord, ...]:
    """Account `name`'s API tokens from its file; ConfigError naming the account and token."""
    records = []
    for n, table in enumerate(tables, 1):
        try:
            records.append(TokenRecord(table.id, table.sha256, parse_created(table.created)))
        except ConfigError as exc:
            raise ConfigError(f"account {name}: token {n}: {exc}") from None
    return tuple(records)


def dump_accounts(accounts: Accounts) -> str:
    """The TOML text of an accounts file."""
    lines = ["# gridfleet broker accounts: keep this file private (mode 600).", ""]
    for a in sorted(accounts.accounts.values(), key=lambda a: (ROLES.index(a.role), a.name)):
        lines.append(f"[accounts.{a.name}]")
        lines.append(f"password = {_string(a.password)}")
        lines.append(f"role = {_string(a.role)}")
        if a.unit is not None:
            lines.append(f"unit = {_string(a.unit)}")
        if a.vehicles:
            lines.append("vehicles = [")
            for v in a.vehicles:
                bound = "" if v.client_id is None else f", client_id = {_string(v.client_id)}"
                lines.append(
                    f"    {{ unit = {_string(v.unit)}, topic = {_string(v.topic)}{bound} }},"
                )
            lines.append("]")
        if a.tokens:
            lines.append("tokens = [")
            for t in a.tokens:
                lines.append(
                    f"    {{ id = {_string(t.id)}, sha256 = {_string(t.sha256)}, "
                    f"created = {_string(created_text(t.created))} }},"
                )
            lines.append("]")
        lines.append("")
    return "\n".join(lines)


def _string(value: str) -> str:
    """`value` as a TOML basic string (JSON's escapes are TOML's)."""
    return json.dumps(value, ensure_ascii=False)


def write_accounts(accounts: Accounts, path: str | Path) -> None:
    """Write an accounts file readable by its owner only (created 0600, never world-readable).

    Whole or not at all: written beside it and renamed over it (through a symlink, its target),
    so a reader (the dashboard re-reads it when it changes) never sees half a file.
    """
    p = Path(path).resolve()
    fd, temporary = tempfile.mkstemp(dir=p.parent, prefix=f".{p.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(dump_accounts(accounts))
            out.flush()
            os.fsync(out.fileno())
        os.replace(temporary, p)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


@dataclass(frozen=True)
class Rules:
    """The topic filters one account may publish to and subscribe to."""

    publish: tuple[str, ...]
    subscribe: tuple[str, ...]


BridgeDirection = Literal["out", "in", "both"]


@dataclass(frozen=True)
class BridgeTopic:
    """One topic filter a hall broker's bridge carries: `out` to the central broker, `in` from it."""

    pattern: str
    direction: BridgeDirection
    qos: int


def bridge_topics(topics: Topics) -> tuple[BridgeTopic, ...]:
    """What a hall broker (its units and devices) and the central one (coordinator, people) share.

    Out, what the hall's units and devices say; in, what they are told and read (orders, goals,
    the latch, the coordinator's status); both ways the presses (pressed in a hall, cleared by the
    coordinator after a release) and the units' states (units of other halls are seen by their
    state). Each at the QoS protocol.md gives its topic. Nothing else crosses: the views (map,
    jobs, routes, events) and the requests stay on the central broker. docs/brokers.md says why.
    """
    t = topics

    def unit(kind: str, direction: BridgeDirection) -> BridgeTopic:
        return BridgeTopic(t.all_units(kind), direction, TOPICS[kind].qos)

    return (
        *(unit(k, "out") for k in UNIT_OWN_KINDS if k not in ("state", "stop")),
        unit("vehicle", "out"),
        BridgeTopic(t.all_devices("device_connection"), "out", TOPICS["device_connection"].qos),
        BridgeTopic(t.fleet("errors"), "out", TOPICS["errors"].qos),
        unit("state", "both"),
        unit("stop", "both"),
        BridgeTopic(t.all_devices("device_stop"), "both", TOPICS["device_stop"].qos),
        unit("order", "in"),
        unit("goal", "in"),
        BridgeTopic(t.fleet("estop"), "in", TOPICS["estop"].qos),
        BridgeTopic(t.fleet("coordinator"), "in", TOPICS["coordinator"].qos),
    )


def rules(account: Account, topics: Topics) -> Rules:
    """What `account` may publish and read, from protocol.md's topic table.

    Only the coordinator and the people's side write the stop's latch (`fleet/estop`): units and
    devices press their own `stop` topic, which can only engage (protocol.md §5.1).
    """
    t = topics
    presses = [t.all_units("stop"), t.all_devices("device_stop")]
    if account.role == "coordinator":
        publish = [
            t.all_units("order"),
            *(
                t.fleet(k)
                for k in (
                    "map",
                    "jobs",
                    "routes",
                    "events",
                    "energy",
                    "zones",  # the zones closed (protocol.md §5.11)
                    "errors",
                    "coordinator",
                    "estop",
                )
            ),
            f"{t.prefix}/replies/+",
            f"{t.prefix}/audit/replies/+",  # pages of the audit trail (protocol.md §6.8)
            f"{t.prefix}/history/replies/+",  # pages of the job history (protocol.md §6.10)
            *presses,  # cleared after an operator's release
            # A removed unit's retained topics, cleared (protocol.md §6.11).
            *(t.all_units(k) for k in REMOVED_UNIT_KINDS),
        ]
        subscribe = [
            *(t.all_units(k) for k in ("connection", "factsheet", "state")),
            t.fleet("estop"),
            t.fleet("coordinator"),  # its own status, heard back: it can hear (world.py)
            t.fleet("errors"),  # components' failed handlers, for its metrics
            *presses,
            t.all_requests,
        ]
    elif account.role == "unit":
        assert account.unit is not None
        publish = [*(t.unit(k, account.unit) for k in UNIT_OWN_KINDS), t.fleet("errors")]
        subscribe = [
            t.unit("order", account.unit),
            t.unit("goal", account.unit),
            # Its own record, set right when a late last will overwrites it (protocol.md §4.1).
            t.unit("connection", account.unit),
            t.fleet("estop"),
            *presses,
            t.fleet("coordinator"),
            t.all_units("state"),  # units elsewhere, seen by their state
        ]
    elif account.role == "device":
        assert account.unit is not None
        own_press = t.device("device_stop", account.name)
        publish = [t.device("device_connection", account.name), own_press, t.fleet("errors")]
        subscribe = [t.unit("direction", account.unit), t.fleet("estop"), own_press]
    elif account.role == "vehicle":
        (vehicle,) = account.vehicles
        publish = [f"{vehicle.topic}/{k}" for k in VDA_FROM_VEHICLE]
        subscribe = [f"{vehicle.topic}/{k}" for k in VDA_TO_VEHICLE]
    elif account.role == "vda5050":
        # Each vehicle's unit, as a unit's account would (it may press the stop for a vehicle
        # whose own e-stop is pressed), and the vehicles' orders and instant actions.
        links = account.vehicles
        publish = [
            *(t.unit(k, v.unit) for v in links for k in (*UNIT_OWN_KINDS, "vehicle")),
            t.fleet("errors"),
            *(f"{v.topic}/{k}" for v in links for k in VDA_TO_VEHICLE),
        ]
        subscribe = [
            *(t.unit("order", v.unit) for v in links),
            *(t.unit("connection", v.unit) for v in links),  # each unit's record, set right
            t.fleet("coordinator"),  # a new session is told again who each unit is (§5.5)
            t.fleet("estop"),
            *presses,
            t.fleet("routes"),  # operators' pauses
            *(f"{v.topic}/{k}" for v in links for k in VDA_FROM_VEHICLE),
        ]
    elif account.role == "bridge":
        # A hall broker's bridge, on the central broker: what the hall's own accounts may say
        # there, they checked at the hall.
        carried = bridge_topics(t)
        publish = [b.pattern for b in carried if b.direction in ("out", "both")]
        subscribe = [b.pattern for b in carried if b.direction in ("in", "both")]
    elif account.role == "alerts":
        # It reads what its rules watch and answers acknowledgements (protocol.md §5.8, §6.7).
        publish = [t.fleet("alerts"), t.fleet("errors"), f"{t.prefix}/replies/+"]
        subscribe = [
            *(t.all_units(k) for k in ("connection", "state")),
            # The energy view: its thresholds and plans (battery_low, cannot_reach_charger).
            *(t.fleet(k) for k in ("jobs", "coordinator", "energy")),
            *presses,
            t.fleet("estop"),
            t.request("ack_alert"),
            t.fleet("alerts"),  # its own view: a restarted process takes over what it says
            t.fleet("errors"),  # components' failed handlers (handler_failures)
        ]
    elif account.role == "viewer":
        publish = []  # reads everything, changes nothing
        # Everything but the audit's replies (`audit/replies/+`): the audit is for operators.
        # Nor the dashboard's revocations (`broker/revoke`), which the embedded broker keeps.
        tops = sorted(
            {spec.pattern.split("/")[0] for spec in TOPICS.values()} - {"audit", "broker"}
        )
        subscribe = [f"{t.prefix}/{top}/#" for top in tops]
    else:  # dashboard, operator: the people's side
        publish = [
            *(t.request(k) for k in REQUEST_KINDS),
            t.all_units("goal"),
            t.fleet("estop"),
        ]
        if account.role == "dashboard":
            publish += [t.request(k) for k in DASHBOARD_REQUEST_KINDS]
            # A page session's broker password taken back at its logout (protocol.md §10).
            publish.append(t.fleet("revoke"))
        subscribe = [f"{t.prefix}/#"]
    return Rules(tuple(publish), tuple(subscribe))
