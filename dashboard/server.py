"""Run the dashboard's Flask app in a background thread (tests, `gridfleet up`), over HTTP or
HTTPS."""

from __future__ import annotations

import ssl
import threading
from types import TracebackType

from flask import Flask
from werkzeug.serving import BaseWSGIServer, WSGIRequestHandler, make_server


class _Quiet(WSGIRequestHandler):
    """werkzeug's handler without its banner (`Server: Werkzeug/3.1 Python/3.11`): versions
    tell a visitor which known flaws to try."""

    server_version = "gridfleet"
    sys_version = ""

    def version_string(self) -> str:
        return self.server_version


class DashboardServer:
    """A threaded werkzeug server for one app; port 0 picks a free port."""

    def __init__(
        self,
        app: Flask,
        host: str = "127.0.0.1",
        port: int = 0,
        tls: ssl.SSLContext | None = None,
    ) -> None:
        self.app = app
        self.host = host
        self.requested_port = port
        self.tls = tls
        self._server: BaseWSGIServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        """The bound port."""
        assert self._server is not None, "dashboard server not started"
        return int(self._server.server_port)

    @property
    def url(self) -> str:
        """e.g. http://127.0.0.1:5000 (https:// with TLS)"""
        return f"{'https' if self.tls else 'http'}://{self.host}:{self.port}"

    def bind(self) -> DashboardServer:
        """Open the listening socket (so `url` is known) without serving yet; returns self."""
        if self._server is None:
            self._server = make_server(
                self.host,
                self.requested_port,
                self.app,
                threaded=True,
                ssl_context=self.tls,
                request_handler=_Quiet,
            )
        return self

    def start(self) -> DashboardServer:
        """Bind and serve in a daemon thread; returns self."""
        self.bind()
        assert self._server is not None
        self._thread = threading.Thread(
            target=self._server.serve_forever, name="gridfleet-dashboard", daemon=True
        )
        self._thread.start()
        return self

    def serve_forever(self) -> None:
        """Bind (unless bound) and serve in this thread until interrupted."""
        self.bind()
        assert self._server is not None
        try:
            self._server.serve_forever()
        finally:
            self._server.server_close()

    def stop(self) -> None:
        """Stop serving and close the socket."""
        if self._server is None:
            return
        self._server.shutdown()
        self._server.server_close()
        api = self.app.extensions.get("gridfleet_api")
        if api is not None:
            api.clients.close()  # the HTTP API's connections to the broker
        if self._thread is not None:
            self._thread.join(5)
        self._server = None
        self._thread = None

    def __enter__(self) -> DashboardServer:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
