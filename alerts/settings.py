"""The alert rules' thresholds and the webhook: defaults, then a TOML `[alerts]` table, then flags.

Pure: values in, a checked AlertSettings out, or one ConfigError line naming the bad value.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from gridfleet.errors import ConfigError
from gridfleet.textfile import read_text

# The coordinator's status goes out at least every 5 s (protocol.md §5.5): a shorter silence is
# no sign of anything.
MIN_COORDINATOR_DOWN_S = 10.0
OFF_WORDS = ("off", "false", "none")


@dataclass(frozen=True)
class AlertSettings:
    """How long a condition must last before it raises; None turns a rule off."""

    unit_lost_s: float | None = 30.0  # a unit not heard from (no state) for this long
    unit_stuck_s: float | None = 120.0  # a unit waiting or holding on one square this long
    job_queued_s: float | None = 600.0  # a job still queued (not assigned) after this long
    # A job waiting on closed zones (wait zone_closed or unreachable, protocol.md §5.3) this
    # long: job_queued's 600 s by default (such a job is not told by job_queued as well).
    zone_wait_s: float | None = 600.0
    estop: bool = True  # the emergency stop engaged (at once)
    step_rate_below: float | None = 0.5  # achieved step rate under this share of the nominal
    coordinator_down_s: float | None = 15.0  # no coordinator online (or no status) this long
    broker_down_s: float | None = 10.0  # the alerts process cut off from the broker this long
    # A component told of a failed handler on `errors` (at once); cleared when none for this long.
    handler_failures_s: float | None = 300.0
    # Energy (read against the coordinator's thresholds in `fleet/energy`): a unit below "good"
    # that neither charges nor is on its way to a charger, at or below "critical" and not
    # charging, or one the energy view says cannot reach any charger ("stranded"), this long.
    battery_low_s: float | None = 60.0
    battery_critical_s: float | None = 10.0
    cannot_reach_charger_s: float | None = 5.0
    webhook: str | None = None  # where each raise, clear and acknowledgement is POSTed
    webhook_queue: str | None = None  # SQLite file keeping undelivered notices (None: memory)

    def __post_init__(self) -> None:
        for name in (
            "unit_lost_s",
            "unit_stuck_s",
            "job_queued_s",
            "zone_wait_s",
            "broker_down_s",
            "handler_failures_s",
            "battery_low_s",
            "battery_critical_s",
            "cannot_reach_charger_s",
        ):
            _check_seconds(name, getattr(self, name))
        _check_seconds("coordinator_down_s", self.coordinator_down_s)
        if self.coordinator_down_s is not None and self.coordinator_down_s < MIN_COORDINATOR_DOWN_S:
            raise ConfigError(
                f"coordinator_down_s {self.coordinator_down_s:g}: give at least "
                f"{MIN_COORDINATOR_DOWN_S:g} s (its status comes every 5 s), or off"
            )
        rate = self.step_rate_below
        number = isinstance(rate, int | float) and not isinstance(rate, bool)
        if rate is not None and not (number and 0 < rate <= 1):
            raise ConfigError(
                f"step_rate_below {rate!r}: give a share of the nominal step rate in (0, 1] "
                "(0.5: alert below half), or off"
            )
        if self.webhook is not None:
            check_webhook_url(self.webhook)


def _check_seconds(name: str, value: float | None) -> None:
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if value is not None and not (number and math.isfinite(value) and value > 0):
        raise ConfigError(f"{name} {value!r}: give a number of seconds > 0, or off")


def check_webhook_url(url: str) -> str:
    """`url` when it is an http(s) URL with a host; else ConfigError (never echoing a secret)."""
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 - raises ValueError for a bad port
    except ValueError:
        raise ConfigError("webhook: not a URL: give http(s)://host[:port]/path") from None
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ConfigError(
            f"webhook: {parts.scheme or 'no'} scheme or no host: give http(s)://host[:port]/path"
        )
    return url


def webhook_where(url: str) -> str:
    """The webhook's scheme, host and port, for logs: its path and query may hold a secret."""
    parts = urlsplit(url)
    port = f":{parts.port}" if parts.port else ""
    return f"{parts.scheme}://{parts.hostname}{port}/…"


_NAMES = {f.name for f in fields(AlertSettings)}
_NUMBERS = _NAMES - {"estop", "webhook", "webhook_queue"}


def with_value(settings: AlertSettings, name: str, value: Any, where: str) -> AlertSettings:
    """`settings` with `name` set to `value` (a TOML value or a flag's word); ConfigError if bad."""
    if name not in _NAMES:
        known = ", ".join(sorted(_NAMES))
        raise ConfigError(f"{where}: unknown alert setting {name!r} (known: {known})")
    if name == "estop":
        if isinstance(value, str) and value.lower() in ("on", "true", *OFF_WORDS):
            value = value.lower() in ("on", "true")
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: estop is true or false")
    elif name in _NUMBERS:
        value = _number(name, value, where)
    elif not isinstance(value, str) or not value:
        raise ConfigError(f"{where}: {name} is a non-empty string")
    try:
        return replace(settings, **{name: value})
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _number(name: str, value: Any, where: str) -> float | None:
    if value is False or (isinstance(value, str) and value.lower() in OFF_WORDS):
        return None
    if isinstance(value, bool):
        raise ConfigError(f"{where}: {name} is a number, or false (off)")
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            pass
    raise ConfigError(f"{where}: {name} {value!r} is not a number (or off)")


def load_settings(path: str | Path, base: AlertSettings | None = None) -> AlertSettings:
    """`base` (default: the defaults) changed by the `[alerts]` table of the TOML file `path`."""
    p = Path(path)
    try:
        data = tomllib.loads(read_text(p, "alerts config", ConfigError))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: cannot read the alerts config: {exc}") from None
    table = data.get("alerts", {})
    if not isinstance(table, dict):
        raise ConfigError(f"{p}: [alerts] must be a table")
    settings = base or AlertSettings()
    for name, value in table.items():
        settings = with_value(settings, name, value, str(p))
    if settings.webhook_queue is not None and "webhook_queue" in table:
        # Beside the config file, wherever the alerts process is started.
        settings = replace(settings, webhook_queue=str(p.parent / settings.webhook_queue))
    return settings


def with_flag(settings: AlertSettings, text: str) -> AlertSettings:
    """`settings` changed by one `--rule NAME=VALUE` flag."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise ConfigError(
            f"--rule {text!r}: give NAME=VALUE, e.g. unit_lost_s=30 or unit_stuck_s=off"
        )
    return with_value(settings, name.strip(), value.strip(), f"--rule {text}")
