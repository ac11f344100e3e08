"""Serving a component's metrics in the Prometheus text format: `/metrics` over plain HTTP.

prometheus_client's WSGI app, behind a bearer-token check, in a wsgiref server on a thread of its
own: a scrape never waits for the component's event loop to be idle, nor holds it up. Beyond
loopback a token is required (anyone on the network could otherwise read the fleet's figures).
Each component keeps its own CollectorRegistry, so several in one process never clash.
"""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import hmac
import logging
import socket
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from socketserver import ThreadingMixIn
from typing import Any, TypeVar
from wsgiref.simple_server import WSGIRequestHandler, WSGIServer, make_server

from prometheus_client import CollectorRegistry, make_wsgi_app

from gridfleet.config import host_of, is_loopback
from gridfleet.errors import ConfigError

log = logging.getLogger("gridfleet.metrics")

DEFAULT_LISTEN = "127.0.0.1"
LOOP_WAIT_S = 5.0  # a scrape waits this long for the component's event loop, then fails (500)
MIN_TOKEN_CHARS = 16  # a shorter token file is refused: a token is only as good as it is long
T = TypeVar("T")
StartResponse = Callable[..., Any]
WsgiApp = Callable[[dict[str, Any], StartResponse], Iterable[bytes]]


@dataclass(frozen=True)
class MetricsOptions:
    """Where to serve `/metrics` (port 0: a free one) and the token a scrape must carry, if any."""

    port: int
    listen: str = DEFAULT_LISTEN
    token: str | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"--metrics {self.port}: give a port from 1 to 65535 (0: a free one)")
        if self.token is None and not is_loopback(self.listen):
            raise ConfigError(
                f"serving metrics on {self.listen} lets anyone on that network read them: give "
                "--metrics-token-file FILE (scrapes then carry 'Authorization: Bearer <token>'), "
                "or serve on 127.0.0.1"
            )


def add_metrics_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """--metrics PORT, --metrics-listen ADDR and --metrics-token-file FILE."""
    parser.add_argument(
        "--metrics",
        type=int,
        default=None,
        metavar="PORT",
        help=f"serve {what}'s metrics in the Prometheus format on http://ADDR:PORT/metrics "
        "(0: a free port; default: not served)",
    )
    parser.add_argument(
        "--metrics-listen",
        default=DEFAULT_LISTEN,
        metavar="ADDR",
        help=f"address the metrics listen on (default {DEFAULT_LISTEN}; any other needs "
        "--metrics-token-file)",
    )
    parser.add_argument(
        "--metrics-token-file",
        type=Path,
        default=None,
        metavar="FILE",
        help="a file holding the token every scrape must send as 'Authorization: Bearer <token>'",
    )


def metrics_options(args: argparse.Namespace) -> MetricsOptions | None:
    """The metrics the flags ask for (None: not served); a bad flag raises ConfigError."""
    if args.metrics is None:
        if args.metrics_token_file is not None or args.metrics_listen != DEFAULT_LISTEN:
            raise ConfigError("--metrics-listen and --metrics-token-file need --metrics PORT")
        return None
    token = None if args.metrics_token_file is None else read_token(args.metrics_token_file)
    return MetricsOptions(args.metrics, args.metrics_listen, token)


def read_token(path: Path) -> str:
    """The bearer token in `path` (surrounding whitespace dropped); ConfigError if unusable."""
    try:
        token = path.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"--metrics-token-file {path}: cannot read it: {exc}") from None
    if not token or not token.isascii() or not token.isprintable() or " " in token:
        raise ConfigError(
            f"--metrics-token-file {path}: give one token of visible ASCII characters "
            "(e.g. from 'openssl rand -hex 32')"
        )
    if len(token) < MIN_TOKEN_CHARS:
        raise ConfigError(
            f"--metrics-token-file {path}: the token is {len(token)} characters, give at least "
            f"{MIN_TOKEN_CHARS} (e.g. from 'openssl rand -hex 32')"
        )
    return token


def guarded(app: WsgiApp, token: str | None, loopback_only: bool = False) -> WsgiApp:
    """`app`, answering 401 to any request without `Authorization: Bearer <token>` (if set), and,
    if `loopback_only`, 403 to one whose Host header names no loopback address or `localhost`.

    A page on another site whose name its DNS points at 127.0.0.1 (DNS rebinding) reaches a
    loopback port as its own origin, and reads what comes back: its Host header is its own name.
    """
    expected = None if token is None else f"Bearer {token}".encode()

    def check(environ: dict[str, Any], start_response: StartResponse) -> Iterable[bytes]:
        host = str(environ.get("HTTP_HOST", ""))
        if loopback_only and not _names_loopback(host):
            start_response("403 Forbidden", [("Content-Type", "text/plain; charset=utf-8")])
            return [
                f"403 Forbidden: Host {host[:100]!r} is not a loopback name or address; these "
                "metrics answer only at 127.0.0.1, [::1] or localhost\n".encode()
            ]
        if expected is None:
            return app(environ, start_response)
        # WSGI hands headers over as latin-1 strings; compared in constant time all the same.
        given = str(environ.get("HTTP_AUTHORIZATION", "")).encode("latin-1", "replace")
        if hmac.compare_digest(given, expected):
            return app(environ, start_response)
        start_response(
            "401 Unauthorized",
            [
                ("Content-Type", "text/plain; charset=utf-8"),
                ("WWW-Authenticate", 'Bearer realm="gridfleet metrics"'),
            ],
        )
        return [b"401 Unauthorized: send 'Authorization: Bearer <token>'\n"]

    return check


def _names_loopback(host: str) -> bool:
    """Whether a Host header (`127.0.0.1:9464`, `[::1]`, `localhost`) names a loopback address."""
    try:
        return is_loopback(host_of(host))
    except ValueError:  # `[::1` and the like: no host at all
        return False


def read_on_loop(loop: asyncio.AbstractEventLoop | None, read: Callable[[], T]) -> T:
    """`read()` run on the component's `loop`: never half-way through a change it makes."""
    try:
        running: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
    except RuntimeError:
        running = None
    if loop is None or not loop.is_running() or running is loop:
        return read()  # nothing to wait for: no loop runs, or this is it (a test reading)
    done: concurrent.futures.Future[T] = concurrent.futures.Future()

    def on_loop() -> None:
        try:
            done.set_result(read())
        except Exception as exc:  # handed to the scrape, which answers 500
            done.set_exception(exc)

    loop.call_soon_threadsafe(on_loop)
    return done.result(LOOP_WAIT_S)


class _Server(ThreadingMixIn, WSGIServer):
    daemon_threads = True  # a scraper that hangs up half-way never keeps the component alive


class _Quiet(WSGIRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:
        # A scrape every few seconds would flood the component's log.
        log.debug("%s %s", self.address_string(), format % args)


class MetricsServer:
    """`/metrics` of `registry` on a thread of its own: `start()` binds (or raises ConfigError)."""

    def __init__(self, registry: CollectorRegistry, options: MetricsOptions) -> None:
        self.options = options
        loopback = is_loopback(options.listen)
        self._app = guarded(make_wsgi_app(registry), options.token, loopback_only=loopback)
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        """The port bound (the free one picked, for port 0)."""
        assert self._server is not None, "not started"
        return int(self._server.server_address[1])

    @property
    def url(self) -> str:
        """Where a scraper finds the metrics."""
        host = self.options.listen
        return f"http://{f'[{host}]' if ':' in host else host}:{self.port}/metrics"

    def start(self) -> MetricsServer:
        """Bind and serve in a thread; a port that cannot be bound raises ConfigError."""
        server_class = _Server
        if ":" in self.options.listen:  # an IPv6 address

            class _Server6(_Server):
                address_family = socket.AF_INET6

            server_class = _Server6
        try:
            server = make_server(
                self.options.listen,
                self.options.port,
                self._app,
                server_class=server_class,
                handler_class=_Quiet,
            )
        except OSError as exc:
            where = f"{self.options.listen}:{self.options.port}"
            raise ConfigError(
                f"--metrics: cannot listen on {where}: {exc.strerror or exc}"
            ) from None
        assert isinstance(server, _Server)
        self._server = server
        self._thread = threading.Thread(
            target=server.serve_forever, kwargs={"poll_interval": 0.2}, name="metrics", daemon=True
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the port (waits for the serving thread)."""
        if self._server is None:
            return
        self._server.shutdown()
        self._server.server_close()
        if self._thread is not None:
            self._thread.join(10)
        self._server = self._thread = None
