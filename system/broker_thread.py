"""An embedded broker on free loopback ports, run in a thread so sync and async tests share it."""

from __future__ import annotations

import asyncio
import threading
from concurrent.futures import Future
from dataclasses import replace
from types import TracebackType

from gridfleet.broker.embedded import BrokerSettings, EmbeddedBroker


async def _end_leftovers() -> None:
    """Cancel every other task of this loop and let them end."""
    others = asyncio.all_tasks() - {asyncio.current_task()}
    for task in others:
        task.cancel()
    if others:
        await asyncio.wait(others, timeout=2.0)


class BrokerThread:
    """Runs EmbeddedBroker in its own thread and event loop; `with` starts and stops it."""

    def __init__(self, settings: BrokerSettings | None = None) -> None:
        self.settings = settings or BrokerSettings(port=0, ws_port=0)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._broker: EmbeddedBroker | None = None

    @property
    def url(self) -> str:
        """TCP URL, e.g. mqtt://127.0.0.1:41234 (mqtts:// with TLS)."""
        assert self._broker is not None, "broker not started"
        return self._broker.url

    @property
    def ws_url(self) -> str:
        """Websocket URL, e.g. ws://127.0.0.1:41235 (wss:// with TLS)."""
        assert self._broker is not None and self._broker.ws_url is not None
        return self._broker.ws_url

    @property
    def port(self) -> int:
        """The bound TCP port."""
        assert self._broker is not None and self._broker.port is not None
        return self._broker.port

    @property
    def ws_port(self) -> int:
        """The bound websocket port."""
        assert self._broker is not None and self._broker.ws_port is not None
        return self._broker.ws_port

    def start(self, timeout: float = 10.0) -> None:
        """Start the broker and wait until it listens."""
        ready: Future[None] = Future()
        self._loop = asyncio.new_event_loop()

        def runner() -> None:
            assert self._loop is not None
            asyncio.set_event_loop(self._loop)
            self._broker = EmbeddedBroker(self.settings)
            try:
                self._loop.run_until_complete(self._broker.start())
            except BaseException as exc:
                ready.set_exception(exc)
                return
            ready.set_result(None)
            self._loop.run_forever()

        self._thread = threading.Thread(target=runner, name="gridfleet-broker", daemon=True)
        self._thread.start()
        ready.result(timeout)

    def stop(self, timeout: float = 10.0) -> None:
        """Shut the broker down (every client is disconnected) and end the thread."""
        if self._loop is None or self._broker is None:
            return
        fut = asyncio.run_coroutine_threadsafe(self._broker.stop(), self._loop)
        fut.result(timeout)
        # What amqtt left running would be collected after the loop is closed, each complaining.
        asyncio.run_coroutine_threadsafe(_end_leftovers(), self._loop).result(timeout)
        self._loop.call_soon_threadsafe(self._loop.stop)
        if self._thread is not None:
            self._thread.join(timeout)
        self._loop.close()
        self._loop = None
        # Keep the same ports (and accounts, certificate) for a restart, as a real broker would.
        self.settings = replace(
            self.settings, port=self._broker.port or 0, ws_port=self._broker.ws_port
        )
        self._broker = None

    def allow_origins(self, *origins: str, timeout: float = 10.0) -> None:
        """Let the web pages of `origins` use the websocket listener too, now and after a restart
        (a dashboard served after the broker started)."""
        self.settings = replace(self.settings, ws_origins=(*self.settings.ws_origins, *origins))
        if self._loop is None or self._broker is None:
            return
        done: Future[None] = Future()
        broker = self._broker

        def allow() -> None:
            broker.allow_origins(origins)
            done.set_result(None)

        self._loop.call_soon_threadsafe(allow)
        done.result(timeout)

    def restart(self) -> None:
        """Stop and start again on the same ports."""
        self.stop()
        self.start()

    def __enter__(self) -> BrokerThread:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
