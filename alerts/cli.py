"""`gridfleet alerts`: run the alerts process; `--list` shows its alerts, `--ack ID` acknowledges one."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import secrets
import sys
from pathlib import Path

import aiomqtt

from gridfleet.alerts.settings import (
    AlertSettings,
    check_webhook_url,
    load_settings,
    with_flag,
    with_value,
)
from gridfleet.alerts.shell import AlertsShell
from gridfleet.bus import connect_first
from gridfleet.config import broker_login, owned_client_id
from gridfleet.endpoint import payload_of, send
from gridfleet.errors import ConfigError, GridfleetError, ProtocolError
from gridfleet.heap import freeze_after_start
from gridfleet.metrics import add_metrics_arguments, metrics_options
from gridfleet.options import accounts_of, add_common, broker_url
from gridfleet.outbound import Outbound
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    TOPICS,
    HeaderStamper,
    Reply,
    Topics,
    decode,
    validate_id,
)
from gridfleet.protocol.messages import AckAlert, AlertEntry, AlertsView
from gridfleet.tasks import stop_on_signals

WAIT_S = 10.0  # --list and --ack: how long to wait for the view or the reply
RETRY_S = 1.0  # an acknowledgement not answered is sent again (same id), the wait doubling


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet alerts`."""
    add_common(parser)
    what = parser.add_mutually_exclusive_group()
    what.add_argument(
        "--list", action="store_true", help="print the alerts in force and the latest cleared"
    )
    what.add_argument("--ack", metavar="ID", help="acknowledge the alert ID (as your account)")
    parser.add_argument(
        "--timeout",
        type=float,
        default=WAIT_S,
        metavar="S",
        help=f"--list, --ack: how long to wait for the alerts process (default {WAIT_S:g} s)",
    )
    parser.add_argument(
        "--config", type=Path, metavar="FILE", help="TOML file with an [alerts] table (the rules)"
    )
    parser.add_argument(
        "--rule",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set one rule, e.g. unit_lost_s=30, job_queued_s=600, step_rate_below=0.5, "
        "estop=off (repeatable; wins over --config)",
    )
    parser.add_argument(
        "--zone-wait-s",
        metavar="S",
        help="zone_wait: how long a job may wait on closed zones before a warning (default "
        "600, as job_queued_s; off turns the rule off); the same as --rule zone_wait_s=S",
    )
    parser.add_argument(
        "--webhook", metavar="URL", help="POST each raise, clear and acknowledgement here (JSON)"
    )
    parser.add_argument(
        "--webhook-queue",
        metavar="FILE",
        help="SQLite file keeping notices the receiver has not taken yet, across restarts "
        "(default: in memory)",
    )
    add_metrics_arguments(parser, "the alerts process")


def settings_from(args: argparse.Namespace) -> AlertSettings:
    """Defaults, then the config file, then --rule flags, then --zone-wait-s, --webhook and
    --webhook-queue."""
    settings = load_settings(args.config) if args.config else AlertSettings()
    for text in args.rule:
        settings = with_flag(settings, text)
    if args.zone_wait_s is not None:
        settings = with_value(settings, "zone_wait_s", args.zone_wait_s, "--zone-wait-s")
    if args.webhook is not None:
        settings = with_flag(settings, f"webhook={check_webhook_url(args.webhook)}")
    if args.webhook_queue is not None:
        settings = with_flag(settings, f"webhook_queue={args.webhook_queue}")
    return settings


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet alerts`."""
    if not args.timeout > 0:
        raise ConfigError(f"--timeout {args.timeout:g}: give seconds > 0")
    try:
        topics = Topics(args.root)
    except ProtocolError as exc:
        raise ConfigError(f"--root: {exc}") from None
    if args.list:
        return asyncio.run(list_alerts(broker_url(args, "operator"), topics, args.timeout))
    if args.ack is not None:
        try:
            alert_id = validate_id(args.ack, "alert id")
        except ProtocolError as exc:
            raise ConfigError(f"--ack: {exc}") from None
        return asyncio.run(ack_alert(broker_url(args, "operator"), topics, alert_id, args.timeout))
    settings = settings_from(args)
    metrics = metrics_options(args)
    accounts = accounts_of(args)
    roles = None if accounts is None else {a.name: a.role for a in accounts.accounts.values()}
    shell = AlertsShell(
        broker_url(args, "alerts"), settings, root=args.root, accounts=roles, metrics=metrics
    )

    async def main() -> None:
        freeze_after_start()
        await shell.run(stop_on_signals())

    asyncio.run(main())
    return 0


# ---- the client side: --list and --ack ---------------------------------------------------------


def _client_id(url: str) -> str:
    """This command's client id (one its account owns), with a random part: one per run."""
    return owned_client_id(broker_login(url), f"alerts-cli-{secrets.token_hex(3)}")


async def list_alerts(url: str, topics: Topics, timeout: float) -> int:
    """Print the retained alerts view; 2 when none comes within `timeout`."""
    async with connect_first(url, _client_id(url)) as client:
        await client.subscribe(topics.fleet("alerts"), qos=SUBSCRIBE_QOS)
        try:
            async with asyncio.timeout(timeout):
                async for message in client.messages:
                    payload = payload_of(message)
                    if payload:
                        view = decode(AlertsView, payload, TOPICS["alerts"].max_bytes)
                        break
        except TimeoutError:
            raise GridfleetError(
                f"no alerts view under {topics.root!r} within {timeout:g} s: "
                "is 'gridfleet alerts' running?"
            ) from None
    print(render(view))
    return 0


def render(view: AlertsView) -> str:
    """The view as a table for people."""
    lines = [f"active: {len(view.active)}"]
    lines += _table(view.active)
    lines.append("")
    lines.append(f"cleared (the latest {len(view.cleared)}):")
    lines += _table(view.cleared)
    return "\n".join(lines)


def _table(alerts: list[AlertEntry]) -> list[str]:
    rows = [("id", "rule", "severity", "raised", "cleared", "acknowledged by", "what")]
    for a in alerts:
        rows.append(
            (
                a.id,
                a.rule,
                a.severity,
                a.raised_at.strftime("%Y-%m-%d %H:%M:%S"),
                a.cleared_at.strftime("%H:%M:%S") if a.cleared_at else "-",
                a.acked_by or "-",
                a.text,
            )
        )
    if len(rows) == 1:
        return ["  (none)"]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]) - 1)]
    return [
        "  " + "  ".join([*(c.ljust(w) for c, w in zip(r, widths, strict=False)), r[-1]])
        for r in rows
    ]


async def ack_alert(url: str, topics: Topics, alert_id: str, timeout: float) -> int:
    """Acknowledge `alert_id`; 0 when accepted, 1 when refused (printed in one line)."""
    client_id = _client_id(url)
    stamp = HeaderStamper(client_id)
    request = AckAlert(
        header=stamp("ack_alert"),
        request_id=f"{client_id}-1"[-64:],
        reply_to=client_id,
        alert_id=alert_id,
    )
    out = Outbound.of("ack_alert", topics.request("ack_alert"), request)
    async with connect_first(url, client_id) as client:
        await client.subscribe(topics.reply(client_id), qos=SUBSCRIBE_QOS)
        reply = await _until_replied(client, out, request.request_id, timeout)
    if reply is None:
        raise GridfleetError(
            f"no reply to ack_alert {request.request_id} within {timeout:g} s: is 'gridfleet "
            "alerts' running, and may this account acknowledge alerts?"
        )
    if not reply.accepted:
        print(f"refused: {reply.reason}")
        return 1
    print(f"acknowledged {alert_id}")
    return 0


async def _until_replied(
    client: aiomqtt.Client, out: Outbound, request_id: str, timeout: float
) -> Reply | None:
    """Send `out` again (the same request) until its reply comes; None after `timeout`."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    messages = aiter(client.messages)
    pause = RETRY_S
    while (left := deadline - loop.time()) > 0:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(send(client, out), left)
        until = min(deadline, loop.time() + pause)
        while (wait := until - loop.time()) > 0:
            try:
                message = await asyncio.wait_for(anext(messages), wait)
            except TimeoutError:
                break
            try:
                reply = decode(Reply, payload_of(message))
            except ProtocolError as exc:
                print(f"gridfleet alerts: ignored a bad reply: {exc}", file=sys.stderr)
                continue
            if reply.request_id == request_id:
                return reply
        pause *= 2
    return None
